"""Motion segmentation and the flow/segmentation fusion loop: numpy (and torch) in, typed results out, no ROS."""
