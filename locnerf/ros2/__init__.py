"""ROS 2 on Zenoh (rmw_zenoh) wire format, without ROS: type names and hashes, CDR through
rosbags, key expressions, attachments, liveliness tokens and the conversions between ROS
messages and locnerf's frames. Pure: nothing here touches a Zenoh session (see docs/ROS2.md)."""
