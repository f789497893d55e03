"""softsnap_driver."""
