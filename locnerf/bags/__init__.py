"""ROS 2 bags (rosbag2, MCAP or SQLite3): read as sensor events, written from data sets and from what the filter publishes."""
