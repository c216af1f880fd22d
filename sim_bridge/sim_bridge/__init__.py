"""sim_bridge: a closed-loop LiDAR traffic simulator with exact ground truth."""
