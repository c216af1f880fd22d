"""`ssf eval odom` and `ssf bench odom`: the odometry variants and KISS-ICP on the same simulated scans."""
