"""The planner core: RDA-style MPC (CasADi) with route, kinematic models, avoidance geometry, frames; no ROS."""
