"""Robot models the controllers use (no ROS): URDF through Pinocchio, compiled chains."""
