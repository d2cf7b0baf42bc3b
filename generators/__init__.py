"""univtac_data.generators"""
