"""softsnap_gaits."""
