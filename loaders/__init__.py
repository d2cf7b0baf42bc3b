"""univtac_data.loaders"""
