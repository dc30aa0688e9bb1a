"""ROS 2 on Zenoh for the services: a node speaking rmw_zenoh over the Bus, and the filter's bridge."""
