"""`ssf odom run`, `ssf eval odom` and `ssf bench odom`: odometry over anyone's scans, and every variant and KISS-ICP on
the same simulated scans."""
