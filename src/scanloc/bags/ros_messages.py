"""scanloc's arrays as ROS messages and back: LaserScan, Odometry, TF, OccupancyGrid, poses.

Messages are built with rosbags' type stores (ROS 2 Humble for CDR, ROS 1 Noetic for ROS 1
serialisation), so no ROS installation is needed. Two conventions make a run survive a round
trip through a bag bit for bit:
- headings: a planar quaternion (0, 0, sin θ/2, cos θ/2) decodes as θ = 2·atan2(z, w), which
  misses θ by an ulp on ~7 % of headings; `yaw_quaternions` picks, among the quaternions within
  one ulp per component of the plain one (all equally valid unit quaternions), one that decodes
  to θ exactly;
- ranges: REP 117: a reading beyond range_max (scanloc's "no return" fill) is written as +inf;
  the reader turns +inf (and every other no-return convention: read.py) back into the
  sensor's fill value.
Times are the run's times after a fixed epoch (EPOCH_NS), never the wall clock.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

EPOCH_NS = 1_600_000_000 * 10**9  # 2020-09-13 12:26:40 UTC: step time 0 of an exported run
_INFINITE = QosTime(sec=2147483647, nsec=4294967295)  # rosbag2's "infinite" duration
LATCHED_QOS = Qos(
    history=QosHistory.KEEP_LAST,
    depth=1,
    reliability=QosReliability.RELIABLE,
    durability=QosDurability.TRANSIENT_LOCAL,
    deadline=_INFINITE,
    lifespan=_INFINITE,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_INFINITE,
    avoid_ros_namespace_conventions=False,
)
SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
GRID = "nav_msgs/msg/OccupancyGrid"
TF_MSG_DEFINITION = "geometry_msgs/TransformStamped[] transforms"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_TYPES = (POSE_COV_STAMPED, POSE_STAMPED, ODOMETRY)
# (row, col) of x, y and yaw in ROS's row-major 6×6 pose covariance, per scanloc COV column.
ROS_COV_INDEX = {
    "cov_xx": 0,
    "cov_xy": 1,
    "cov_xt": 5,
    "cov_yy": 7,
    "cov_yt": 11,
    "cov_tt": 35,
}


def stamps_ns(times: np.ndarray, epoch_ns: int = EPOCH_NS) -> np.ndarray:
    """int64 nanosecond stamps of run times (seconds after the epoch)."""
    return epoch_ns + np.round(np.asarray(times, dtype=np.float64) * 1e9).astype(np.int64)


def _decodes_to(z: float, w: float, yaw: float) -> bool:
    return 2.0 * math.atan2(z, w) == yaw


def _exact_quaternion(yaw: float) -> tuple[float, float]:
    """(z, w) near (sin θ/2, cos θ/2) whose 2·atan2(z, w) is exactly θ (libm, as decoded)."""
    z0, w0 = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    for dz in (0, -1, 1):
        z = z0 if dz == 0 else math.nextafter(z0, dz * math.inf)
        for dw in (0, -1, 1):
            w = w0 if dw == 0 else math.nextafter(w0, dw * math.inf)
            if _decodes_to(z, w, yaw):
                return z, w
    return z0, w0  # none within an ulp (θ/2 underflows): the plain one


def yaw_quaternions(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z, w) of planar quaternions that `quaternion_yaw` decodes to exactly `yaw` (module doc).

    Computed one value at a time through libm (math), like the decoder: numpy's SIMD kernels
    may differ in the last bit from one CPU to the next.
    """
    yaw = np.asarray(yaw, dtype=np.float64)
    pairs = np.array([_exact_quaternion(t) for t in yaw.reshape(-1).tolist()], dtype=np.float64)
    pairs = pairs.reshape(*yaw.shape, 2)
    return pairs[..., 0], pairs[..., 1]


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The heading (rotation about z) of a quaternion, in (−π, π]; 2·atan2(z, w) when planar."""
    if x == 0.0 and y == 0.0:
        yaw = 2.0 * math.atan2(z, w)
    else:
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    if not -math.pi < yaw <= math.pi:  # wrapping costs exactness: only where needed
        yaw = math.pi - math.fmod(math.pi - yaw, 2.0 * math.pi)
    return yaw


def stamp_of(header: Any) -> int:
    """A header's stamp in nanoseconds."""
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)


def planar_pose(pose: Any) -> tuple[float, float, float]:
    """(x, y, yaw) of a geometry_msgs/Pose."""
    q = pose.orientation
    return float(pose.position.x), float(pose.position.y), quaternion_yaw(q.x, q.y, q.z, q.w)


def estimate_of(msgtype: str, msg: Any) -> tuple[int, tuple[float, float, float], np.ndarray]:
    """(stamp ns, (x, y, yaw), the 6 scanloc covariance entries or NaN) of a pose message."""
    cov = np.full(len(ROS_COV_INDEX), np.nan)
    if msgtype == POSE_STAMPED:
        pose = msg.pose
    else:  # PoseWithCovarianceStamped and Odometry: pose.pose, pose.covariance
        pose = msg.pose.pose
        cov = np.asarray(msg.pose.covariance, dtype=np.float64)[list(ROS_COV_INDEX.values())]
    return stamp_of(msg.header), planar_pose(pose), cov


class MessageFactory:
    """Builds and serialises the exported topics' messages for ROS 1 or ROS 2."""

    def __init__(self, ros1: bool) -> None:
        self.ros1 = ros1
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if TF not in self.store.fielddefs:  # rosbags' Noetic store lacks tf2_msgs
            self.store.register(get_types_from_msg(TF_MSG_DEFINITION, TF))
        self.types = self.store.types

    def serialize(self, msg: Any) -> bytes:
        if self.ros1:
            return bytes(self.store.serialize_ros1(msg, msg.__msgtype__))
        return bytes(self.store.serialize_cdr(msg, msg.__msgtype__))

    def header(self, ns: int, frame: str) -> Any:
        stamp = self.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        if self.ros1:
            return self.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def pose(self, x: float, y: float, qz: float, qw: float) -> Any:
        t = self.types
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(qz), w=float(qw)),
        )

    def laser_scan(self, ns: int, frame: str, spec: LaserSpec, ranges: np.ndarray) -> Any:
        """A LaserScan of one run scan (float32 ranges; beyond range_max → +inf, REP 117)."""
        readings = np.asarray(ranges, dtype=np.float32)
        readings = np.where(readings > np.float32(spec.range_max), np.float32(np.inf), readings)
        return self.types[SCAN](
            header=self.header(ns, frame),
            angle_min=spec.angle_min,
            angle_max=spec.angle_max,
            angle_increment=spec.angle_increment,
            time_increment=0.0,
            scan_time=1.0 / spec.rate_hz,
            range_min=spec.range_min,
            range_max=spec.range_max,
            ranges=readings.astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    def odometry(self, ns: int, frame: str, child: str, pose: tuple[float, ...]) -> Any:
        """nav_msgs/Odometry with the pose (x, y, qz, qw), zero covariance and twist."""
        t = self.types
        zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return t[ODOMETRY](
            header=self.header(ns, frame),
            child_frame_id=child,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=self.pose(*pose), covariance=np.zeros(36)
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=np.zeros(36),
            ),
        )

    def tf(self, ns: int, parent: str, child: str, pose: tuple[float, ...]) -> Any:
        """A TFMessage with one transform parent → child, pose (x, y, qz, qw)."""
        t = self.types
        x, y, qz, qw = pose
        transform = t["geometry_msgs/msg/TransformStamped"](
            header=self.header(ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=0.0),
                rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(qz), w=float(qw)),
            ),
        )
        return t[TF](transforms=[transform])

    def occupancy_grid(self, ns: int, frame: str, grid: OccupancyGrid) -> Any:
        """The map as nav_msgs/OccupancyGrid (row 0 at the bottom, as scanloc stores it)."""
        t = self.types
        ox, oy, _ = grid.origin
        info = t["nav_msgs/msg/MapMetaData"](
            map_load_time=self.header(ns, frame).stamp,
            resolution=grid.resolution,
            width=grid.width,
            height=grid.height,
            origin=self.pose(ox, oy, 0.0, 1.0),
        )
        data = np.ascontiguousarray(grid.cells, dtype=np.int8).reshape(-1)
        return t[GRID](header=self.header(ns, frame), info=info, data=data)
