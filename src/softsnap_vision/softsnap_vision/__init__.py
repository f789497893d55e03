"""softsnap_vision: camera measurement of SoftSnap module shapes.

Core modules (numpy, scipy and OpenCV; no rclpy): :mod:`.camera_info` (intrinsics,
distortion, back-projection onto the marker plane), :mod:`.marker_config` (marker colours
and sizes, YAML), :mod:`.blobs` (colour markers and their centres), :mod:`.chain` (module
base frame and rib order), :mod:`.measurement` (one module in one image),
:mod:`.tracker` (every module of a scene in one image, by ArUco tag), :mod:`.validation`
(batch RMSE per threading and step), :mod:`.calibrate_camera` (intrinsics from boards).
Shells: :mod:`.measure` (CLI) and :mod:`.marker_tracker_node` (ROS node).
"""
