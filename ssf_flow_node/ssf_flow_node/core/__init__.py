"""Scene flow cores: numpy in, numpy out, no ROS."""
