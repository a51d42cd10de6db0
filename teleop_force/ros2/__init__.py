"""ROS 2 on Zenoh: rmw_zenoh's key expressions, liveliness tokens and attachment, CDR messages.

A process that follows these conventions is a peer of ROS 2 nodes running
``RMW_IMPLEMENTATION=rmw_zenoh_cpp``: ``ros2 topic list`` sees its topics, ``ros2 topic echo``
decodes its messages, and it hears ROS 2 publishers, with no ROS installed here and no bridge.

- :mod:`.graph`: data keys, liveliness tokens and GIDs exactly as rmw_zenoh builds them;
- :mod:`.attachment`: the 33-byte per-sample attachment (sequence number, source time, GID);
- :mod:`.interfaces`: the message types (standard and ``teleop_force_msgs``) and their RIHS01
  hashes, from ``rosbags``;
- :mod:`.codec`: the project's messages to and from CDR payloads, with ``rosbags``;
- :mod:`.node`: a node on a Zenoh session that declares its tokens, publishes and subscribes.
"""
