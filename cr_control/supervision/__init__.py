"""Supervision policy of the two nodes, free of ROS: what a node does with each message it
takes (follow one publisher, check sizes and values, rate-limit its complaints), as plain
objects a node hands its messages to and a test drives without a middleware.

Nothing here imports rclpy: a node wraps these objects, subscribes and publishes.
"""
