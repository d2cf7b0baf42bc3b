"""The ``univtac-data`` command line."""
