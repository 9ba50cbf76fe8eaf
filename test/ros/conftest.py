"""test/ros uses the shared ROS fixtures of test/conftest.py (ros_env, ros_context, ros_process)."""
