"""softsnap_model."""
