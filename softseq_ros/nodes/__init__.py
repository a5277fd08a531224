"""ROS 2 nodes: thin wrappers that turn parameters and messages into physics calls."""
