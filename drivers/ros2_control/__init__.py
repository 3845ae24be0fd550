"""An arm behind ros2_control, reached over DDS as a ROS 2 node (the 'ros2' extra)."""
