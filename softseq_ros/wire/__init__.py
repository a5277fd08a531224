"""
The wire: what travels on the rig's topics and into its bags, beneath both the rig and the bag.

``contract`` names every topic (relative name, type, QoS, producer, consumers), ``values`` holds
the typed value each topic carries, ``cdr`` encodes ROS 2 messages to CDR bytes without rclpy,
and ``payloads`` turns values into those bytes and received messages (or recorded JSON) back
into values. The rig's cores, the nodes, the batch runner, the bag's tools and the analysis all
speak through it; it imports none of them, so data flows one way: rig -> wire <- bag.
"""
