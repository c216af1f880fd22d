"""Topic names of the graph, in one place."""

LIDAR_POINTS = "/lidar/points"
FLOW = "/ssf/flow"
EGO_MOTION = "/ssf/ego_motion"  # the flow estimator's ego motion of each /ssf/flow (ssf_interfaces/EgoMotion)
MASK = "/ssf/mask"
MASK_HINT = "/ssf/mask_hint"
PRIOR = "/ssf/prior"  # a finished scan's points near its movers, moved by their flow: the next scan's prior
SEMANTIC_FLOW = "/ssf/semantic_flow"
OBSTACLES = "/ssf/obstacles"
FUSION_STATE = "/ssf/fusion_state"
ODOM = "/odom"
TF = "/tf"
PATH = "/ssf/path"
MAP = "/ssf/map"
CMD_VEL = "/cmd_vel"
PLAN = "/ssf/plan"
PLANNER_STATE = "/ssf/planner_state"  # one MPC tick: status, solve time, rounds, obstacles, clearance
CLOCK = "/clock"
GT_FLOW = "/sim/ground_truth/flow"
GT_OBSTACLES = "/sim/ground_truth/obstacles"
GT_ODOM = "/sim/ground_truth/odom"
EPISODE = "/sim/episode"
MARKERS = "/sim/markers"
SSF_MARKERS = "/ssf/markers"  # perceived obstacles, their velocity arrows and the plan (visualization_msgs/MarkerArray)
VEHICLE_TWIST = "/vehicle/twist"  # the vehicle's own wheel speed and yaw rate (geometry_msgs/TwistStamped)
ROUTE = "/sim/route"  # the route A -> B in the odometry frame (latched nav_msgs/Path)
DIAGNOSTICS = "/diagnostics"
