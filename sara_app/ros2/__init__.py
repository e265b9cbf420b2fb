"""ROS 2 over Zenoh, without ROS: the cell's optional bridge to a ROS 2 system that runs
rmw_zenoh (``scenario.ros2``).

- :mod:`.interfaces`: the message types (JointState, MarkerArray and what they use), their CDR
  codec (Foxglove's ``mcap_ros2``) and REP 2016 type hashes;
- :mod:`.topics`: rmw_zenoh's key expressions, sample attachments and liveliness tokens;
- :mod:`.convert`: the cell's messages to and from ROS 2 messages;
- :mod:`.bridge`: the bridge process.
"""
