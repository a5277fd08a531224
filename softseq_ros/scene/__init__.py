"""What a user writes: scenes, segment designs, pump programmes, tables from CSV, limits, paths.

Every mistake in a file is one line naming the file, the key and what is wrong
(softseq_ros.scene.validation). No ROS imports here.
"""
