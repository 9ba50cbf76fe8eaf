"""The pure core of wind_shaper: geometry, prior model, field estimation, update rules, loop.

Nothing here imports rclpy; the ROS nodes translate messages into calls on this package.
"""
