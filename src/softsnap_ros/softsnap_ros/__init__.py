"""softsnap_ros: the ROS plumbing at the bottom of the SoftSnap stack (docs/architecture.md)."""
