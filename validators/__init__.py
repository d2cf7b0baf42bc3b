"""univtac_data.validators"""
