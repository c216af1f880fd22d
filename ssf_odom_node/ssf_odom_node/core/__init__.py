"""Odometry core (no ROS): registration from static points and their flow, the pose chain, the static map."""
