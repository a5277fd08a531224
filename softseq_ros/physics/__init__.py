"""Pure physics: segment models, equilibrium tracking, kinematics, scenes. No ROS imports here."""
