"""The rig's ROS-free cores (pump, actuator, camera) and the one topic contract they share."""
