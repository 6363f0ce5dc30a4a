"""``rfhoming node``: the homing run as a ROS 2 node (rclpy). :mod:`.progress` turns the loop's
state into what the node publishes and needs nothing of ROS 2; :mod:`.node` is the rclpy node,
imported only by the command (rclpy is the ``ros2node`` extra, or the system's ROS 2)."""
