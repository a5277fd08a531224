"""Segment models: tables, closed-form membrane laws, smoothing, kinematics, identity.

Pure numpy/scipy, no ROS, and no file is read here: softseq_ros.scene turns files into these.
"""
