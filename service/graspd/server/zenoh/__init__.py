"""graspd.server.zenoh: the Zenoh entrance (queryables for detect, templates and ROS-bridge streams)."""
