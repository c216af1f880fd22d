"""ssf_odom_node: odometry from the static part of the scene and its flow."""
