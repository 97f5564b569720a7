"""Readers for recorded laser logs and writers for trajectories.

- CARMEN logs (``.clf``/``.log``): ``FLASER``, ``ROBOTLASER1`` and ``RAWLASER1`` lines
  with their embedded odometry; the format of the Freiburg / Radish SLAM benchmark data.
- ROS 1 / ROS 2 bags (``rosbags``, pure Python): ``sensor_msgs/LaserScan`` with odometry
  from ``nav_msgs/Odometry`` or, without it, the ``odom`` frame's transforms on ``/tf``,
  interpolated to each scan's stamp; the laser mount from ``/tf_static``. A log is written
  as a ROS 2 bag (MCAP) the same way, and a trajectory as a ``nav_msgs/Path`` bag.
- TUM trajectories (``t x y z qx qy qz qw``), as evo and most SLAM tools read them.
- Relation files of Kümmerle et al. 2009 (``t1 t2 x y z roll pitch yaw``).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Literal

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, relative, wrap_angle
from chizu.numeric.scan import LaserLog, Scan, beam_angles

#: Usable range cap for the benchmark logs: their no-return codes are 50-82 m and the
#: SICK LMS beams beyond ~40 m are mostly spurious.
DEFAULT_MAX_RANGE_M = 40.0


def _flaser_angles(n: int) -> np.ndarray:
    """CARMEN FLASER convention: 180 (360) beams at 1 (0.5) degree from -90 degrees;
    181 (361) beams spread evenly over [-90, +90] degrees."""
    step = np.pi / (n - (n % 2)) if n > 1 else 0.0
    return beam_angles(n, -np.pi / 2, step)


def read_carmen(path: str | Path, max_range_m: float = DEFAULT_MAX_RANGE_M,
                limit: int | None = None) -> LaserLog:
    """Scans of a CARMEN log in file order (``FLASER``, ``ROBOTLASER1``, ``RAWLASER1``).

    The odometry of each scan is the pose embedded in its line (``odom_x odom_y
    odom_theta`` of FLASER, the robot pose of ROBOTLASER1); for ROBOTLASER1 the laser
    mount is the laser pose relative to the robot pose. RAWLASER1 lines carry no pose and
    take the latest ODOM line's. Remissions become intensities when there is one per beam.
    """
    path = Path(path)
    scans: list[Scan] = []
    last_odom = np.zeros(3)
    angle_cache: dict[int, np.ndarray] = {}
    with path.open("r", encoding="ascii", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if limit is not None and len(scans) >= limit:
                break
            tag, _, rest = line.partition(" ")
            if tag not in ("FLASER", "ROBOTLASER1", "RAWLASER1", "ODOM"):
                continue
            try:
                tok = rest.split()
                if tag == "ODOM":
                    last_odom = np.array(tok[0:3], dtype=float)
                    continue
                if tag == "FLASER":
                    n = int(tok[0])
                    ranges = np.array(tok[1:1 + n], dtype=float)
                    odom = np.array(tok[n + 4:n + 7], dtype=float)
                    t = float(tok[n + 7])
                    if n not in angle_cache:
                        angle_cache[n] = _flaser_angles(n)
                    scans.append(Scan(t=t, ranges=ranges, angles=angle_cache[n], odom=odom,
                                      max_range_m=max_range_m))
                    continue
                start, _fov, res, maxr = (float(v) for v in tok[1:5])
                n = int(tok[7])
                ranges = np.array(tok[8:8 + n], dtype=float)
                k = 8 + n
                n_rem = int(tok[k])
                rem = np.array(tok[k + 1:k + 1 + n_rem], dtype=float)
                k += 1 + n_rem
                intens = rem if n_rem == n else None
                cap = min(max_range_m, maxr) if maxr > 0 else max_range_m
                angles = beam_angles(n, start, res)
                if tag == "ROBOTLASER1":
                    laser = np.array(tok[k:k + 3], dtype=float)
                    robot = np.array(tok[k + 3:k + 6], dtype=float)
                    t = float(tok[k + 11])
                    scans.append(Scan(t=t, ranges=ranges, angles=angles, odom=robot,
                                      intensities=intens, max_range_m=cap,
                                      sensor_pose=relative(robot, laser)))
                else:
                    t = float(tok[k])
                    scans.append(Scan(t=t, ranges=ranges, angles=angles,
                                      odom=last_odom.copy(), intensities=intens,
                                      max_range_m=cap))
            except (ValueError, IndexError) as exc:
                raise InvalidInput(f"{path.name}:{lineno}: malformed {tag} line ({exc})",
                                   field="log") from None
    if not scans:
        raise InvalidInput(f"{path.name}: no FLASER/ROBOTLASER1/RAWLASER1 lines", field="log")
    return LaserLog(path.stem.split(".")[0], scans)


def _yaw(q: object) -> float:
    x, y, z, w = (float(getattr(q, k)) for k in ("x", "y", "z", "w"))
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _stamp(header: Any) -> float:
    st = header.stamp
    return float(st.sec) + 1e-9 * float(st.nanosec)


def read_ros_bag(path: str | Path, scan_topic: str | None = None,
                 odom_topic: str | None = None, max_range_m: float = DEFAULT_MAX_RANGE_M,
                 limit: int | None = None) -> LaserLog:
    """Scans of a ROS 1 bag (file) or ROS 2 bag (directory) with ``sensor_msgs/LaserScan``
    and odometry: ``nav_msgs/Odometry``, or where the bag has none, the transforms from
    the ``odom`` frame on ``/tf`` (as a robot's base driver broadcasts them). Odometry is
    interpolated to each scan stamp (held at the ends); the laser mount comes from a
    ``/tf_static`` transform to the scan's frame."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    store = get_typestore(Stores.ROS1_NOETIC)
    raw_scans: list[tuple[float, Any]] = []
    odo_t: list[float] = []
    odo_p: list[tuple[float, float, float]] = []
    mounts: dict[str, np.ndarray] = {}
    try:
        reader = AnyReader([path], default_typestore=store)
    except Exception as exc:  # rosbags raises its own error types per format
        raise InvalidInput(f"{path.name}: not a readable ROS bag ({exc})", field="log") from None
    with reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        scan_topic = scan_topic or next((k for k, v in types.items()
                                         if v == "sensor_msgs/msg/LaserScan"), None)
        odom_topic = odom_topic or next((k for k, v in types.items()
                                         if v == "nav_msgs/msg/Odometry"), None)
        if scan_topic is None or types.get(scan_topic) != "sensor_msgs/msg/LaserScan":
            raise InvalidInput(f"{path.name}: no sensor_msgs/LaserScan topic", field="scan_topic")
        tf_odometry = odom_topic is None and types.get("/tf") == "tf2_msgs/msg/TFMessage"
        if not tf_odometry and (odom_topic is None
                                or types.get(odom_topic) != "nav_msgs/msg/Odometry"):
            raise InvalidInput(f"{path.name}: no nav_msgs/Odometry topic and no /tf",
                               field="odom_topic")
        wanted = [c for c in reader.connections
                  if c.topic in (scan_topic, odom_topic, "/tf_static", "/tf")]
        for con, _t, raw in reader.messages(connections=wanted):
            msg: Any = reader.deserialize(raw, con.msgtype)
            if con.topic == scan_topic:
                if limit is None or len(raw_scans) < limit:
                    raw_scans.append((_stamp(msg.header), msg))
            elif con.topic == odom_topic:
                p = msg.pose.pose
                odo_t.append(_stamp(msg.header))
                odo_p.append((p.position.x, p.position.y, _yaw(p.orientation)))
            elif con.topic == "/tf":
                for tr in msg.transforms:
                    if tf_odometry and tr.header.frame_id.lstrip("/") == "odom":
                        tt = tr.transform
                        odo_t.append(_stamp(tr.header))
                        odo_p.append((tt.translation.x, tt.translation.y, _yaw(tt.rotation)))
            else:
                for tr in msg.transforms:
                    tt = tr.transform
                    mounts[tr.child_frame_id] = np.array(
                        [tt.translation.x, tt.translation.y, _yaw(tt.rotation)])
    if not raw_scans:
        raise InvalidInput(f"{path.name}: no scans on {scan_topic}", field="log")
    if not odo_t:
        raise InvalidInput(f"{path.name}: no odometry on {odom_topic or '/tf'}",
                           field="odom_topic")
    order = np.argsort(odo_t, kind="stable")
    ot = np.asarray(odo_t)[order]
    op = np.asarray(odo_p)[order]
    unwrapped = np.unwrap(op[:, 2])
    scans: list[Scan] = []
    for t, m in sorted(raw_scans, key=lambda s: s[0]):
        odom = np.array([np.interp(t, ot, op[:, 0]), np.interp(t, ot, op[:, 1]),
                         float(wrap_angle(np.interp(t, ot, unwrapped)))])
        ranges = np.asarray(m.ranges, dtype=float)
        n = len(ranges)
        intens = np.asarray(m.intensities, dtype=float)
        cap = min(max_range_m, float(m.range_max))
        ranges = np.where(np.isfinite(ranges), ranges, cap)  # inf / NaN = no return: a miss
        scans.append(Scan(
            t=t, ranges=ranges, odom=odom,
            angles=beam_angles(n, float(m.angle_min),
                               float(m.angle_increment)),
            intensities=intens if len(intens) == n else None,
            min_range_m=max(0.0, float(m.range_min)),
            max_range_m=cap,
            sensor_pose=mounts.get(m.header.frame_id, np.zeros(3))))
    return LaserLog(path.stem.split(".")[0], scans)


def read_log(path: str | Path, max_range_m: float = DEFAULT_MAX_RANGE_M,
             limit: int | None = None) -> LaserLog:
    """A CARMEN log or a ROS bag, chosen by the file name (``.bag``, ``.db3``, ``.mcap``
    or a directory = bag)."""
    p = Path(path)
    if not p.exists():
        raise InvalidInput(f"{p}: no such file", field="log")
    if p.is_dir() or p.suffix in (".bag", ".db3", ".mcap"):
        return read_ros_bag(p, max_range_m=max_range_m, limit=limit)
    return read_carmen(p, max_range_m=max_range_m, limit=limit)


def format_tum(times: np.ndarray, poses: np.ndarray) -> str:
    """One line ``t x y z qx qy qz qw`` per pose (planar: z = qx = qy = 0)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    half = 0.5 * poses[:, 2]
    zero = np.zeros(len(poses))
    rows = np.column_stack([times, poses[:, 0], poses[:, 1], zero, zero, zero,
                            np.sin(half), np.cos(half)])
    buf = io.StringIO()
    np.savetxt(buf, rows, fmt="%.6f")
    return buf.getvalue()


def write_tum(path: str | Path, times: np.ndarray, poses: np.ndarray) -> None:
    """:func:`format_tum` into ``path`` (written to a temporary file, then renamed)."""
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(format_tum(times, poses))
    tmp.replace(path)


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(N,)`` and planar poses ``(N, 3)`` of a TUM trajectory file."""
    try:
        a = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"{path}: not a TUM trajectory ({exc})", field="trajectory") from None
    if a.shape[1] != 8 or len(a) == 0:
        raise InvalidInput(f"{path}: expected 8 columns 't x y z qx qy qz qw'",
                           field="trajectory")
    qx, qy, qz, qw = a[:, 4], a[:, 5], a[:, 6], a[:, 7]
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    return a[:, 0], np.column_stack([a[:, 1], a[:, 2], yaw])


def read_relations(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Time pairs ``(R, 2)`` and relative poses ``(R, 3)`` (pose(t2) in the frame of
    pose(t1)) of a Kümmerle et al. relations file."""
    try:
        a = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"{path}: not a relations file ({exc})", field="relations") from None
    if a.shape[1] != 8:
        raise InvalidInput(f"{path}: expected 8 columns 't1 t2 x y z roll pitch yaw'",
                           field="relations")
    return a[:, 0:2], a[:, [2, 3, 7]]


def write_carmen(path: str | Path, log: LaserLog) -> None:
    """``log`` as CARMEN ``ROBOTLASER1`` lines (with remissions when the scans have
    intensities), readable by :func:`read_carmen` and CARMEN tools."""
    lines = ["# chizu simulated log: ROBOTLASER1 laser_type start_angle fov angular_res "
             "max_range accuracy remission_mode n ranges num_remissions remissions laser_x "
             "laser_y laser_theta robot_x robot_y robot_theta tv rv fsd ssd turn_axis "
             "ipc_timestamp ipc_hostname logger_timestamp"]
    for s in log.scans:
        n = len(s.ranges)
        res = float(s.angles[1] - s.angles[0]) if n > 1 else 0.0
        laser = compose(s.odom, s.sensor_pose)
        rem = s.intensities if s.intensities is not None else np.zeros(0)
        parts = ["ROBOTLASER1 0", f"{s.angles[0]:.9f}", f"{res * (n - 1):.9f}", f"{res:.9f}",
                 f"{s.max_range_m:.3f}", "0.01", "0" if s.intensities is None else "1", str(n),
                 " ".join(f"{r:.3f}" for r in s.ranges), str(len(rem)),
                 " ".join(f"{v:.0f}" for v in rem),
                 " ".join(f"{v:.6f}" for v in (*laser, *s.odom)), "0 0 0 0 0",
                 f"{s.t:.6f} sim {s.t:.6f}"]
        lines.append(" ".join(p for p in parts if p != ""))
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


#: ROS 2 bags are written with the message definitions of this distribution
ROS2_STORE = "ROS2_HUMBLE"


def _ros2_types() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(getattr(Stores, ROS2_STORE))


def _ros_time(ts: Any, t: float) -> Any:
    sec, nanosec = divmod(int(round(t * 1e9)), 10**9)
    return ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def _ros_quaternion(ts: Any, yaw: float) -> Any:
    """The rotation by ``yaw`` about z (the inverse of :func:`_yaw`)."""
    half = 0.5 * float(yaw)
    return ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(half),
                                                    w=np.cos(half))


def _ros_pose(ts: Any, pose: np.ndarray) -> Any:
    return ts.types["geometry_msgs/msg/Pose"](
        position=ts.types["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
        orientation=_ros_quaternion(ts, pose[2]))


def _transform(ts: Any, t: float, parent: str, child: str, pose: np.ndarray) -> Any:
    """A ``geometry_msgs/TransformStamped`` parent -> child of the planar ``pose``."""
    T = ts.types
    return T["geometry_msgs/msg/TransformStamped"](
        header=T["std_msgs/msg/Header"](stamp=_ros_time(ts, t), frame_id=parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(pose[0]), y=float(pose[1]),
                                                       z=0.0),
            rotation=_ros_quaternion(ts, pose[2])))


def _ros2_writer(path: Path) -> Any:
    """A ROS 2 bag (MCAP storage) at the directory ``path``, which must not exist."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    if path.exists():
        raise InvalidInput(f"{path}: exists; a ROS 2 bag is written to a new directory",
                           field="out")
    return Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)


def write_ros2_bag(path: str | Path, log: LaserLog,
                   odometry: Literal["topic", "tf"] = "topic") -> None:
    """``log`` as a ROS 2 bag (MCAP) as a robot's recorder writes one: ``/scan``
    (``sensor_msgs/LaserScan`` in frame ``laser``; a range past ``range_max`` is no return),
    the odometry at each scan's stamp as ``/odom`` (``nav_msgs/Odometry``, odom ->
    base_link) or, with ``odometry="tf"``, as that transform on ``/tf``, and the laser
    mount on ``/tf_static``. :func:`read_ros_bag` reads it back."""
    ts = _ros2_types()
    T = ts.types
    with _ros2_writer(Path(path)) as w:
        c_scan = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_odom = w.add_connection(*(("/odom", "nav_msgs/msg/Odometry") if odometry == "topic"
                                    else ("/tf", "tf2_msgs/msg/TFMessage")), typestore=ts)
        c_tf = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        first = log.scans[0]
        tf = T["tf2_msgs/msg/TFMessage"](transforms=[
            _transform(ts, first.t, "base_link", "laser", first.sensor_pose)])
        w.write(c_tf, int(round(first.t * 1e9)),
                ts.serialize_cdr(tf, "tf2_msgs/msg/TFMessage"))
        zeros36 = np.zeros(36)
        for s in log.scans:
            stamp = _ros_time(ts, s.t)
            n = len(s.ranges)
            inc = float(s.angles[1] - s.angles[0]) if n > 1 else 0.0
            scan = T["sensor_msgs/msg/LaserScan"](
                header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="laser"),
                angle_min=float(s.angles[0]), angle_max=float(s.angles[-1]),
                angle_increment=inc, time_increment=0.0, scan_time=0.0,
                range_min=float(s.min_range_m), range_max=float(s.max_range_m),
                ranges=s.ranges.astype(np.float32),
                intensities=(s.intensities if s.intensities is not None
                             else np.zeros(0)).astype(np.float32))
            if odometry == "topic":
                vec = T["geometry_msgs/msg/Vector3"]
                odom = T["nav_msgs/msg/Odometry"](
                    header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="odom"),
                    child_frame_id="base_link",
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](
                        pose=_ros_pose(ts, s.odom), covariance=zeros36),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](linear=vec(x=0.0, y=0.0, z=0.0),
                                                           angular=vec(x=0.0, y=0.0, z=0.0)),
                        covariance=zeros36))
            else:
                odom = T["tf2_msgs/msg/TFMessage"](transforms=[
                    _transform(ts, s.t, "odom", "base_link", s.odom)])
            t_ns = int(round(s.t * 1e9))
            w.write(c_odom, t_ns, ts.serialize_cdr(odom, c_odom.msgtype))
            w.write(c_scan, t_ns, ts.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))


def write_ros2_path(path: str | Path, times: np.ndarray, poses: np.ndarray,
                    frame_id: str = "map") -> None:
    """A trajectory as a ROS 2 bag (MCAP) of one ``nav_msgs/Path`` on ``/trajectory``:
    every pose stamped with its scan's time, in ``frame_id``; beside the TUM file."""
    ts = _ros2_types()
    T = ts.types
    times = np.asarray(times, dtype=float)
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    header = T["std_msgs/msg/Header"]
    msg = T["nav_msgs/msg/Path"](
        header=header(stamp=_ros_time(ts, float(times[-1]) if len(times) else 0.0),
                      frame_id=frame_id),
        poses=[T["geometry_msgs/msg/PoseStamped"](
            header=header(stamp=_ros_time(ts, float(t)), frame_id=frame_id),
            pose=_ros_pose(ts, p)) for t, p in zip(times, poses, strict=True)])
    with _ros2_writer(Path(path)) as w:
        c = w.add_connection("/trajectory", "nav_msgs/msg/Path", typestore=ts)
        w.write(c, int(round(float(times[-1]) * 1e9)) if len(times) else 0,
                ts.serialize_cdr(msg, "nav_msgs/msg/Path"))


def read_ros2_path(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The last ``nav_msgs/Path`` of a bag: (times, poses (N, 3))."""
    from rosbags.highlevel import AnyReader

    last: Any = None
    with AnyReader([Path(path)], default_typestore=_ros2_types()) as reader:
        cons = [c for c in reader.connections if c.msgtype == "nav_msgs/msg/Path"]
        if not cons:
            raise InvalidInput(f"{Path(path).name}: no nav_msgs/Path topic", field="path")
        for con, _t, raw in reader.messages(connections=cons):
            last = reader.deserialize(raw, con.msgtype)
    assert last is not None
    times = np.array([_stamp(p.header) for p in last.poses])
    poses = np.array([(p.pose.position.x, p.pose.position.y, _yaw(p.pose.orientation))
                      for p in last.poses]).reshape(-1, 3)
    return times, poses
