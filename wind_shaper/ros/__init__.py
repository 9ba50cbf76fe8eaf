"""The ROS layer's shared pieces: names, parameters, conversions, QoS, the node runner.

Nodes (``wind_shaper.nodes``) are thin: they translate messages and parameters into calls on the
pure core and back. Everything here may import rclpy; nothing in ``wind_shaper.core`` does.
"""
