"""MCAP bags in the rosbag2 layout: writing, reading, playback."""
