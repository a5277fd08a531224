"""
Time in the physics: the fluid network between the syringe and the segments, integrated.

Pure numpy/scipy, no ROS. The same segment models as the quasi-static solver give each
segment's pressure from its volume; the tubes of the scene's ``network`` block
(softseq_ros.scene.network) set how fast fluid moves between them.
"""
