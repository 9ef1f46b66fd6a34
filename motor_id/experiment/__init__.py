"""A live experiment on one joint of a ROS 2 robot: the plan, the guard, the record, the
identification (no rclpy here; the node is :mod:`motor_id.nodes.experiment`)."""
