"""The quasi-static solver: assembly, states, the equilibrium map, tracking, reach, history.

Pure numpy/scipy, no ROS: where several segments on one supply sit, and where they snap.
"""
