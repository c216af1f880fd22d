"""ssf_planner_node: RDA-style MPC that avoids moving obstacles."""
