"""Records (`ssf_common.records`) to and from ROS messages: what every node does at its edges.

Readers validate what they take and raise MessageError with one line naming the problem."""

from __future__ import annotations

from typing import Any

import numpy as np

from ssf_common import messages, pose_msgs
from ssf_common.errors import MessageError
from ssf_common.pointcloud import cloud_to_array, decode_cloud, xyz_to_cloud
from ssf_common.geometry.se3 import yaw_of
from ssf_common.records import (EgoMotion, MotionMask, Obstacles, OdometryEstimate, Plan, PriorSource, SceneFlow,
                                Segmentation, SemanticFlow)

FLOW_FIELDS = ("flow_x", "flow_y", "flow_z")
VELOCITY_COVARIANCE_SIZE = 9


def _fields(points: np.ndarray, names: tuple[str, ...], what: str) -> None:
    present = points.dtype.names or ()
    missing = [name for name in names if name not in present]
    if missing:
        raise MessageError(f"{what} has no {'/'.join(missing)} field (fields: {', '.join(present) or 'none'})")


def _finite_xyz(msg: Any, what: str) -> tuple[np.ndarray, np.ndarray]:
    """All points of a cloud (structured) and their xyz; every point must be finite (these clouds are ours)."""
    decoded = decode_cloud(msg)
    if len(decoded.indices) != len(decoded.points):
        raise MessageError(f"{what} has {len(decoded.points) - len(decoded.indices)} points with NaN/Inf coordinates")
    return decoded.points, decoded.xyz


def _flow_of(points: np.ndarray, what: str) -> np.ndarray:
    _fields(points, FLOW_FIELDS, what)
    flow = np.stack([np.asarray(points[name], dtype=np.float32) for name in FLOW_FIELDS], axis=1)
    if not np.isfinite(flow).all():
        raise MessageError(f"{what} has NaN/Inf flow values")
    return flow


def _iteration_of(points: np.ndarray) -> int:
    return int(points["iteration"][0]) if "iteration" in (points.dtype.names or ()) and len(points) else 0


def _probabilities(values: np.ndarray, what: str) -> np.ndarray:
    prob = np.asarray(values, dtype=np.float32)
    if not np.isfinite(prob).all() or (prob.size and (prob.min() < 0 or prob.max() > 1)):
        raise MessageError(f"{what} values must be finite probabilities in [0, 1]")
    return prob


def _time_fields(time: np.ndarray | None) -> dict[str, np.ndarray]:
    """The `time` field (float32 s relative to the stamp, as velodyne_pointcloud writes it) where a sweep has time."""
    return {} if time is None else {"time": np.asarray(time, dtype=np.float32)}


def _time_of(points: np.ndarray, what: str) -> np.ndarray | None:
    """The `time` field of one of our clouds (None without one)."""
    if "time" not in (points.dtype.names or ()):
        return None
    time = np.asarray(points["time"], dtype=np.float32)
    if not np.isfinite(time).all():
        raise MessageError(f"{what} has NaN/Inf per-point times")
    return time


def scene_flow_to_cloud(flow: SceneFlow) -> Any:
    """/ssf/flow: x y z flow_x flow_y flow_z iteration (constant per point) prior (the dynamic probability the flow
    was conditioned on; 0 without one), and time where the scan's points carry it. Its ego motion travels on
    /ssf/ego_motion (`ego_motion_to_msg`)."""
    prior = np.zeros(len(flow.points), np.float32) if flow.prior is None else np.asarray(flow.prior, np.float32)
    return xyz_to_cloud(flow.points, messages.header(flow.stamp_ns, flow.frame_id),
                        flow_x=flow.flow[:, 0], flow_y=flow.flow[:, 1], flow_z=flow.flow[:, 2],
                        iteration=np.full(len(flow.points), flow.iteration, dtype=np.uint32), prior=prior,
                        **_time_fields(flow.time))


def scene_flow_from_cloud(msg: Any) -> SceneFlow:
    """A /ssf/flow cloud as a SceneFlow (its prior None where the cloud has no prior field; no ego motion yet)."""
    points, xyz = _finite_xyz(msg, "flow cloud")
    prior = _probabilities(points["prior"], "flow cloud prior") if "prior" in (points.dtype.names or ()) else None
    return SceneFlow(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, xyz, _flow_of(points, "flow cloud"),
                     _iteration_of(points), prior, time=_time_of(points, "flow cloud"))


def ego_motion_to_msg(ego: EgoMotion) -> Any:
    """ssf_interfaces/EgoMotion."""
    return messages.msg_type("ssf_interfaces/msg/EgoMotion")(
        header=messages.header(ego.stamp_ns, ego.frame_id), next_stamp=messages.stamp(ego.next_stamp_ns),
        iteration=int(ego.iteration), motion=pose_msgs.transform_msg(ego.transform))


def ego_motion_from_msg(msg: Any) -> EgoMotion:
    """An ssf_interfaces/EgoMotion as an EgoMotion, checked (a finite rigid transform, scan t+1 after scan t)."""
    stamp, next_stamp = messages.stamp_ns(msg.header.stamp), messages.stamp_ns(msg.next_stamp)
    if next_stamp <= stamp:
        raise MessageError(f"ego motion's next_stamp {next_stamp} is not after its stamp {stamp}")
    q, t = msg.motion.rotation, msg.motion.translation
    values = np.array([q.x, q.y, q.z, q.w, t.x, t.y, t.z], np.float64)
    if not np.isfinite(values).all() or not 0.5 < np.linalg.norm(values[:4]) < 1.5:
        raise MessageError("ego motion is not a finite rigid transform (NaN/Inf, or a quaternion far from unit length)")
    return EgoMotion(stamp, next_stamp, msg.header.frame_id, pose_msgs.matrix_from_transform(msg.motion),
                     int(msg.iteration))


def prior_to_cloud(source: PriorSource) -> Any:
    """/ssf/prior: x y z mask radius (points moved into the next scan's frame, their dynamic probability, and the
    radius within which they count, constant per point)."""
    return xyz_to_cloud(source.points, messages.header(source.stamp_ns, source.frame_id),
                        mask=np.asarray(source.probability, np.float32),
                        radius=np.full(len(source.points), source.radius, np.float32))


def prior_from_cloud(msg: Any) -> PriorSource:
    """A /ssf/prior cloud as a PriorSource (empty where the scan had no moving point)."""
    if int(msg.width) * int(msg.height) == 0:
        return PriorSource(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, np.zeros((0, 3), np.float32),
                           np.zeros(0, np.float32), 0.0)
    points, xyz = _finite_xyz(msg, "prior cloud")
    _fields(points, ("mask", "radius"), "prior cloud")
    radius = np.asarray(points["radius"], np.float64)
    if not np.isfinite(radius).all() or (radius < 0).any():
        raise MessageError("prior cloud radius must be finite and not negative")
    return PriorSource(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, xyz,
                       _probabilities(points["mask"], "prior cloud mask"), float(radius[0]) if len(radius) else 0.0)


def mask_to_cloud(mask: MotionMask) -> Any:
    """/ssf/mask and /ssf/mask_hint: x y z mask instance iteration (mask = probability that the point moves)."""
    return xyz_to_cloud(mask.points, messages.header(mask.stamp_ns, mask.frame_id),
                        mask=np.asarray(mask.dynamic_prob, dtype=np.float32),
                        instance=np.asarray(mask.instance, dtype=np.int32),
                        iteration=np.full(len(mask.points), mask.iteration, dtype=np.uint32))


def mask_from_cloud(msg: Any, expected_points: int | None = None) -> MotionMask:
    """A mask cloud as a MotionMask, checked against the scan it refers to (when its size is known)."""
    points = cloud_to_array(msg)
    _fields(points, ("mask", "iteration"), "mask cloud")
    if expected_points is not None and len(points) != expected_points:
        raise MessageError(f"mask cloud has {len(points)} points but the scan it refers to has {expected_points}")
    names = points.dtype.names or ()
    xyz = np.zeros((len(points), 3), np.float32)
    if all(name in names for name in ("x", "y", "z")):
        xyz = np.stack([np.asarray(points[name], dtype=np.float32) for name in ("x", "y", "z")], axis=1)
    instance = np.asarray(points["instance"], dtype=np.int32) if "instance" in names else None
    return MotionMask(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, xyz,
                      _probabilities(points["mask"], "mask cloud"), instance, _iteration_of(points))


def semantic_flow_to_cloud(result: SemanticFlow) -> Any:
    """/ssf/semantic_flow: x y z flow_x flow_y flow_z label instance prob iteration (of the flow it answers with,
    constant per point: its ego motion is the /ssf/ego_motion of that stamp and iteration)."""
    seg = result.segmentation
    return xyz_to_cloud(result.points, messages.header(result.stamp_ns, result.frame_id),
                        flow_x=result.flow[:, 0], flow_y=result.flow[:, 1], flow_z=result.flow[:, 2],
                        label=np.asarray(seg.label, dtype=np.uint8), instance=np.asarray(seg.instance, dtype=np.int32),
                        prob=np.asarray(seg.dynamic_prob, dtype=np.float32),
                        iteration=np.full(len(result.points), result.iterations - 1, dtype=np.uint32),
                        **_time_fields(result.time))


def semantic_flow_from_cloud(msg: Any) -> SemanticFlow:
    """A /ssf/semantic_flow cloud as a SemanticFlow."""
    points, xyz = _finite_xyz(msg, "semantic flow cloud")
    _fields(points, ("label", "instance", "prob"), "semantic flow cloud")
    label = np.asarray(points["label"], dtype=np.uint8)
    if label.size and label.max() > 1:
        raise MessageError("semantic flow cloud labels must be 0 (static) or 1 (dynamic)")
    segmentation = Segmentation(_probabilities(points["prob"], "semantic flow cloud prob"), label,
                                np.asarray(points["instance"], dtype=np.int32))
    return SemanticFlow(messages.stamp_ns(msg.header.stamp), msg.header.frame_id, xyz,
                        _flow_of(points, "semantic flow cloud"), segmentation, iterations=_iteration_of(points) + 1,
                        time=_time_of(points, "semantic flow cloud"))


def obstacles_to_msg(obstacles: Obstacles) -> Any:
    """ssf_interfaces/ObstacleArray."""
    make = messages.msg_type("ssf_interfaces/msg/Obstacle")
    pose_type = messages.msg_type("geometry_msgs/msg/Pose")
    items = [
        make(id=int(obstacles.ids[i]), kind=int(obstacles.kinds[i]),
             pose=pose_type(position=pose_msgs.point_msg(obstacles.centres[i]),
                            orientation=pose_msgs.yaw_quaternion_msg(float(obstacles.yaws[i]))),
             size=pose_msgs.vector3_msg(obstacles.sizes[i]), velocity=pose_msgs.vector3_msg(obstacles.velocities[i]),
             velocity_covariance=np.asarray(obstacles.velocity_covariances[i], dtype=np.float64).reshape(9),
             yaw_rate=float(obstacles.yaw_rates[i]), num_points=int(obstacles.point_counts[i]),
             confidence=float(obstacles.confidences[i]))
        for i in range(len(obstacles))
    ]
    return messages.msg_type("ssf_interfaces/msg/ObstacleArray")(
        header=messages.header(obstacles.stamp_ns, obstacles.frame_id), obstacles=items)


def obstacles_from_msg(msg: Any) -> Obstacles:
    """An ObstacleArray as Obstacles (non-finite boxes or velocities are a MessageError)."""
    items = list(msg.obstacles)
    poses = [pose_msgs.matrix_from_pose(item.pose) for item in items]
    obstacles = Obstacles(
        messages.stamp_ns(msg.header.stamp), msg.header.frame_id,
        ids=np.array([item.id for item in items], dtype=np.int64),
        kinds=np.array([item.kind for item in items], dtype=np.uint8),
        centres=np.array([pose[:3, 3] for pose in poses]).reshape(-1, 3),
        sizes=np.array([[item.size.x, item.size.y, item.size.z] for item in items]).reshape(-1, 3),
        yaws=np.array([yaw_of(pose) for pose in poses]),
        velocities=np.array([[item.velocity.x, item.velocity.y, item.velocity.z] for item in items]).reshape(-1, 3),
        velocity_covariances=np.array([np.asarray(item.velocity_covariance, dtype=np.float64) for item in items]).reshape(-1, 3, 3),
        yaw_rates=np.array([item.yaw_rate for item in items]),
        point_counts=np.array([item.num_points for item in items]),
        confidences=np.array([item.confidence for item in items]),
    )
    return _finite(obstacles)


def _finite(obstacles: Obstacles) -> Obstacles:
    for name in ("centres", "sizes", "yaws", "velocities", "velocity_covariances"):
        if not np.isfinite(getattr(obstacles, name)).all():
            raise MessageError(f"obstacle array holds NaN/Inf {name.replace('_', ' ')}")
    return obstacles


# ObstacleArray straight from and to its CDR bytes: an Obstacle is fixed-size, so the array is a numpy record array
# (10 000 obstacles: well under a millisecond, against ~200 ms through message objects). In XCDR1 an element starting
# 4 bytes past an 8-byte boundary is 200 bytes long and so is every one after it; the first may start on the boundary
# (196 bytes, less padding before its pose).
_OBSTACLE_FIELDS = (("id", "<u4"), ("kind", "u1"), ("position", "<f8", 3), ("orientation", "<f8", 4),
                    ("size", "<f8", 3), ("velocity", "<f8", 3), ("velocity_covariance", "<f8", 9),
                    ("yaw_rate", "<f4"), ("num_points", "<u4"), ("confidence", "<f4"))


def _obstacle_dtype(phase: int) -> np.dtype:
    """The record of one Obstacle starting `phase` (0 or 4) bytes past an 8-byte boundary of the CDR body."""
    names, formats, offsets, offset = [], [], [], 0
    for name, kind, *shape in _OBSTACLE_FIELDS:
        base = np.dtype(kind)
        offset += -(phase + offset) % base.itemsize  # XCDR1: each primitive aligned to its size
        names.append(name)
        formats.append((kind, tuple(shape)) if shape else kind)
        offsets.append(offset)
        offset += base.itemsize * (shape[0] if shape else 1)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": offset})


_OBSTACLE_RECORDS = {phase: _obstacle_dtype(phase) for phase in (0, 4)}
_CDR_LE = b"\x00\x01"


def _obstacle_records(body: memoryview, start: int, count: int) -> list[np.ndarray]:
    """The obstacles of a CDR body as record arrays (the first alone when it starts on an 8-byte boundary)."""
    parts, end = [], start
    if count and start % 8 == 0:
        first = _OBSTACLE_RECORDS[0]
        parts.append(np.frombuffer(body, first, 1, start))
        end, count = start + first.itemsize, count - 1
    record = _OBSTACLE_RECORDS[4]
    if end + count * record.itemsize > len(body):
        raise MessageError(f"obstacle array: {count} obstacles do not fit in {len(body)} bytes")
    parts.append(np.frombuffer(body, record, count, end))
    return parts


def obstacles_from_cdr(cdr: bytes | memoryview) -> Obstacles:
    """The Obstacles of an ObstacleArray's CDR bytes, decoded as numpy records (any byte order other than little
    endian goes through the message objects); NaN/Inf or a truncated array are a MessageError."""
    data = memoryview(cdr).cast("B")
    if len(data) < 20 or bytes(data[:2]) != _CDR_LE:
        return obstacles_from_msg(messages.deserialize(cdr, "ssf_interfaces/msg/ObstacleArray"))
    body = data[4:]
    sec, (nanosec, length) = int(np.frombuffer(body, "<i4", 1, 0)[0]), (int(v) for v in np.frombuffer(body, "<u4", 2, 4))
    if length < 1 or 12 + length + 4 > len(body):
        raise MessageError(f"obstacle array: a frame id of {length} bytes does not fit in {len(body)} bytes")
    frame_id = bytes(body[12:12 + length - 1]).decode("utf-8", errors="replace")
    start = 12 + length + (-(12 + length) % 4)
    count = int(np.frombuffer(body, "<u4", 1, start)[0])
    parts = _obstacle_records(body, start + 4, count)
    column = lambda name: np.concatenate([part[name] for part in parts]) if parts else np.zeros(0)  # noqa: E731
    x, y, z, w = (column("orientation")[:, i] for i in range(4)) if count else (np.zeros(0),) * 4
    norm = x * x + y * y + z * z + w * w
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero quaternion gives NaN: refused below
        yaws = np.arctan2(2.0 * (x * y + z * w) / norm, 1.0 - 2.0 * (y * y + z * z) / norm)
    obstacles = Obstacles(
        sec * 1_000_000_000 + nanosec, frame_id, ids=column("id").astype(np.int64),
        kinds=column("kind").astype(np.uint8), centres=column("position").reshape(-1, 3),
        sizes=column("size").reshape(-1, 3), yaws=yaws, velocities=column("velocity").reshape(-1, 3),
        velocity_covariances=column("velocity_covariance").reshape(-1, 3, 3),
        yaw_rates=column("yaw_rate").astype(np.float64), point_counts=column("num_points").astype(np.int64),
        confidences=column("confidence").astype(np.float64))
    return _finite(obstacles)


def obstacles_to_cdr(obstacles: Obstacles) -> bytes:
    """The CDR bytes (little endian) of obstacles_to_msg(obstacles), written as numpy records."""
    frame = obstacles.frame_id.encode() + b"\x00"
    sec, nanosec = divmod(int(obstacles.stamp_ns), 1_000_000_000)
    head = np.array([sec], "<i4").tobytes() + np.array([nanosec, len(frame)], "<u4").tobytes() + frame
    head += b"\x00" * (-len(head) % 4) + np.array([len(obstacles)], "<u4").tobytes()
    body = bytearray(head)
    count = len(obstacles)
    phases = [0, 4] if count and len(head) % 8 == 0 else [4]
    sizes = [_OBSTACLE_RECORDS[phase].itemsize for phase in phases]
    total = len(head) + (sizes[0] + (count - 1) * _OBSTACLE_RECORDS[4].itemsize if count else 0)
    body.extend(b"\x00" * (total - len(head)))
    half = obstacles.yaws / 2.0
    values = {"id": obstacles.ids, "kind": obstacles.kinds, "position": obstacles.centres,
              "orientation": np.c_[np.zeros((count, 2)), np.sin(half), np.cos(half)], "size": obstacles.sizes,
              "velocity": obstacles.velocities, "velocity_covariance": obstacles.velocity_covariances.reshape(-1, 9),
              "yaw_rate": obstacles.yaw_rates, "num_points": obstacles.point_counts, "confidence": obstacles.confidences}
    offset, first = len(head), 0
    for phase in phases:
        record = _OBSTACLE_RECORDS[phase]
        rows = 1 if phase == 0 and len(phases) == 2 else count - first
        view = np.frombuffer(body, record, rows, offset)
        for name, column in values.items():
            view[name] = column[first:first + rows]
        offset, first = offset + rows * record.itemsize, first + rows
    return _CDR_LE + b"\x00\x00" + bytes(body)


def odometry_to_msg(odometry: OdometryEstimate) -> Any:
    """nav_msgs/Odometry: pose in frame_id with covariance, twist in child_frame_id."""
    twist = messages.msg_type("geometry_msgs/msg/Twist")(linear=pose_msgs.vector3_msg(odometry.twist[:3]),
                                                         angular=pose_msgs.vector3_msg(odometry.twist[3:]))
    return messages.msg_type("nav_msgs/msg/Odometry")(
        header=messages.header(odometry.stamp_ns, odometry.frame_id),
        child_frame_id=odometry.child_frame_id,
        pose=messages.msg_type("geometry_msgs/msg/PoseWithCovariance")(
            pose=pose_msgs.pose_msg(odometry.pose), covariance=np.asarray(odometry.pose_covariance, np.float64).reshape(36)),
        twist=messages.msg_type("geometry_msgs/msg/TwistWithCovariance")(
            twist=twist, covariance=np.asarray(odometry.twist_covariance, np.float64).reshape(36)),
    )


def odometry_from_msg(msg: Any) -> OdometryEstimate:
    """A nav_msgs/Odometry as an OdometryEstimate."""
    pose = pose_msgs.matrix_from_pose(msg.pose.pose)
    linear, angular = msg.twist.twist.linear, msg.twist.twist.angular
    twist = np.array([linear.x, linear.y, linear.z, angular.x, angular.y, angular.z])
    if not (np.isfinite(pose).all() and np.isfinite(twist).all()):
        raise MessageError("odometry holds NaN/Inf pose or twist values")
    return OdometryEstimate(messages.stamp_ns(msg.header.stamp), pose,
                            np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6), twist,
                            np.asarray(msg.twist.covariance, dtype=np.float64).reshape(6, 6),
                            msg.header.frame_id, msg.child_frame_id)


def odometry_transform_msg(odometry: OdometryEstimate) -> Any:
    """/tf message with the frame_id -> child_frame_id transform of an odometry estimate."""
    return messages.msg_type("tf2_msgs/msg/TFMessage")(transforms=[pose_msgs.transform_stamped_msg(
        odometry.pose, odometry.stamp_ns, odometry.frame_id, odometry.child_frame_id)])


def plan_to_msg(plan: Plan) -> Any:
    """nav_msgs/Path: one PoseStamped per planned state, stamped at its time."""
    stamped = messages.msg_type("geometry_msgs/msg/PoseStamped")
    pose_type = messages.msg_type("geometry_msgs/msg/Pose")
    poses = [stamped(header=messages.header(plan.stamp_ns + int(round(float(t) * 1e9)), plan.frame_id),
                     pose=pose_type(position=pose_msgs.point_msg(np.array([state[0], state[1], 0.0])),
                                    orientation=pose_msgs.yaw_quaternion_msg(float(state[2]))))
             for t, state in zip(plan.times, plan.states)]
    return messages.msg_type("nav_msgs/msg/Path")(header=messages.header(plan.stamp_ns, plan.frame_id), poses=poses)


def plan_from_msg(msg: Any) -> Plan:
    """A nav_msgs/Path as a Plan (speeds from consecutive poses)."""
    stamp = messages.stamp_ns(msg.header.stamp)
    matrices = [pose_msgs.matrix_from_pose(item.pose) for item in msg.poses]
    times = np.array([(messages.stamp_ns(item.header.stamp) - stamp) * 1e-9 for item in msg.poses])
    xy = np.array([m[:2, 3] for m in matrices]).reshape(-1, 2)
    yaw = np.array([yaw_of(m) for m in matrices])
    speed = np.zeros(len(xy))
    if len(xy) > 1:
        gaps = np.maximum(np.diff(times), 1e-9)
        speed[:-1] = np.linalg.norm(np.diff(xy, axis=0), axis=1) / gaps
        speed[-1] = speed[-2]
    return Plan(stamp, msg.header.frame_id, times, np.column_stack([xy, yaw, speed]))
