"""Topics of a ROS 1 or ROS 2 bag (sqlite3 or mcap) as arrays, in one pass over the bag.

rosbags' AnyReader opens either kind (a ROS 1 `.bag` file, a ROS 2 bag folder, or the .db3 /
.mcap file inside one) with the bag's own message definitions (ROS 2 Humble's where a bag has
none). Stamps are the messages' header stamps, in nanoseconds.

Whatever rosbags raises on a bag it cannot read (a bare AssertionError on an old or broken ROS 1
index, struct errors on a truncated file, a KeyError on an unknown message type, ...) becomes a
BagError naming the bag, the topic ("(none)" where no topic is at fault) and what to do.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.typesys import Stores, get_typestore

from scanloc.bags.errors import BagError
from scanloc.bags.mount import TfSpread
from scanloc.bags.ros_messages import (
    POSE_TYPES,
    SCAN,
    TF,
    estimate_of,
    quaternion_yaw,
    stamp_of,
)

ANGLE_TOLERANCE = 0.5  # of an increment: how far angle_min + (n-1)·increment may miss angle_max
REPAIR = (
    "if it is a ROS 1 bag, reindex it with `rosbag reindex` (or `rosbags-convert` it to ROS 2); "
    "a ROS 2 bag may need `ros2 bag reindex` or `rosbags-convert`"
)


def bag_path(path: str | Path) -> Path:
    """The path AnyReader opens: a ROS 1 .bag file or a ROS 2 bag folder (given it or a file in
    it)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: bag not found")
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        return path.parent
    return path


def frame(name: str) -> str:
    """A frame id without ROS 1's leading slash."""
    return name.lstrip("/")


@dataclass
class ScanStream:
    """The LaserScans of one topic: stamps (N,), raw float32 ranges (N, B), their geometry."""

    stamps: list[int] = field(default_factory=list)
    ranges: list[np.ndarray] = field(default_factory=list)
    geometry: dict[str, Any] = field(default_factory=dict)


@dataclass
class PoseStream:
    """Planar poses of one topic or transform: stamps, (x, y, yaw), 6 covariance entries."""

    stamps: list[int] = field(default_factory=list)
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    covs: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            np.asarray(self.stamps, dtype=np.int64),
            np.asarray(self.poses, dtype=np.float64).reshape(-1, 3),
            np.asarray(self.covs, dtype=np.float64).reshape(-1, 6),
        )


def rosbags_failure(bag: str | Path, topic: str, doing: str, err: BaseException) -> BagError:
    """What rosbags raised, as a BagError that says what to do (module doc)."""
    what = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
    return BagError(bag, topic, f"rosbags could not {doing} ({what}); {REPAIR}")


def open_bag(path: str | Path) -> AnyReader:
    """An opened AnyReader; an unreadable bag is a BagError."""
    where = bag_path(path)
    try:
        reader = AnyReader([where], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, FileNotFoundError, OSError) as err:
        raise BagError(
            path, "(none)", f"not a readable ROS 1 or ROS 2 bag: {err}; {REPAIR}"
        ) from None
    except Exception as err:  # rosbags' own failures: bare asserts, struct errors, ...
        raise rosbags_failure(path, "(none)", "open it", err) from err
    return reader


def close_bag(reader: AnyReader) -> None:
    """Close quietly: a bag that failed mid-read may fail to close too, and the first error
    is the one to report."""
    try:
        reader.close()
    except Exception:  # the read's own error is already on its way
        pass


def messages(
    reader: AnyReader, bag: str | Path, connections: list[Any]
) -> Iterator[tuple[str, Any]]:
    """(topic, deserialised message) of `connections` in bag order; rosbags' failures while
    reading or deserialising are BagErrors (module doc)."""
    stream = iter(reader.messages(connections=connections))
    read = 0
    while True:
        try:
            conn, _, raw = next(stream)
        except StopIteration:
            return
        except Exception as err:
            raise rosbags_failure(bag, "(none)", f"read message {read} of the bag", err) from err
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as err:
            doing = f"deserialise its {conn.msgtype} message"
            raise rosbags_failure(bag, conn.topic, doing, err) from err
        read += 1
        yield conn.topic, msg


def check_topic(reader: AnyReader, bag: str | Path, topic: str, types: Iterable[str]) -> str:
    """The message type of `topic`, which must be in the bag with one of `types`."""
    types = tuple(types)
    info = reader.topics.get(topic)
    if info is None:
        raise BagError(
            bag,
            topic,
            f"missing: expected {' or '.join(types)} messages; the bag has "
            f"{sorted(reader.topics) or 'no topics'}",
        )
    if info.msgtype not in types:
        raise BagError(bag, topic, f"has {info.msgtype} messages, expected {' or '.join(types)}")
    return str(info.msgtype)


def _scan_geometry(msg: Any) -> dict[str, Any]:
    return {
        "frame": frame(msg.header.frame_id),
        "angle_min": float(msg.angle_min),
        "angle_max": float(msg.angle_max),
        "angle_increment": float(msg.angle_increment),
        "range_min": float(msg.range_min),
        "range_max": float(msg.range_max),
        "num_beams": len(msg.ranges),
    }


def _check_scan(bag: str | Path, topic: str, index: int, msg: Any, first: dict[str, Any]) -> None:
    count, inc = len(msg.ranges), float(msg.angle_increment)
    end = float(msg.angle_min) + (count - 1) * inc
    if count < 2 or inc == 0 or abs(end - float(msg.angle_max)) > ANGLE_TOLERANCE * abs(inc):
        expected = (float(msg.angle_max) - float(msg.angle_min)) / inc + 1 if inc else float("nan")
        raise BagError(
            bag,
            topic,
            f"message {index} (stamp {stamp_of(msg.header)} ns) has {count} ranges, but "
            f"angle_min {float(msg.angle_min):.6f} + ({count} - 1) x angle_increment "
            f"{inc:.6f} = {end:.6f} rad misses angle_max {float(msg.angle_max):.6f}: expected "
            f"(angle_max - angle_min) / angle_increment + 1 = {expected:.2f} ranges",
        )
    if first and _scan_geometry(msg) != first:
        raise BagError(
            bag,
            topic,
            f"message {index} has geometry {_scan_geometry(msg)}, expected that of message 0: "
            f"{first}",
        )


@dataclass
class BagTopics:
    """What `read_topics` collected: scans, pose streams by topic, the tf transforms wanted,
    every static transform (parent, child) → (x, y, yaw) and how each transform on tf
    varies (for a laser mount published there, bags/mount.py)."""

    scans: ScanStream
    poses: dict[str, PoseStream]
    transforms: dict[tuple[str, str], PoseStream]
    static: dict[tuple[str, str], tuple[float, float, float]]
    types: dict[str, str]
    dynamic: dict[tuple[str, str], TfSpread] = field(default_factory=dict)


def read_topics(
    bag: str | Path,
    scan_topic: str | None,
    pose_topics: Iterable[str] = (),
    tf_topic: str | None = None,
    tf_pairs: Iterable[tuple[str, str]] = (),
    tf_static_topic: str | None = None,
    tf_required: bool = True,
) -> BagTopics:
    """One pass over the bag: the scans (None: none; checked: geometry, beam count), the pose topics
    (PoseStamped, PoseWithCovarianceStamped, Odometry), the transforms `tf_pairs` of
    `tf_topic` (absent: an error if `tf_required`, else none), and the static transforms of
    `tf_static_topic` (absent: none)."""
    reader = open_bag(bag)
    try:
        types = (
            {}
            if scan_topic is None
            else {scan_topic: check_topic(reader, bag, scan_topic, (SCAN,))}
        )
        for topic in pose_topics:
            types[topic] = check_topic(reader, bag, topic, POSE_TYPES)
        if tf_topic is not None and (tf_required or tf_topic in reader.topics):
            types[tf_topic] = check_topic(reader, bag, tf_topic, (TF,))
        if tf_static_topic is not None and tf_static_topic in reader.topics:
            types[tf_static_topic] = check_topic(reader, bag, tf_static_topic, (TF,))
        wanted = {frame(p): frame(c) for p, c in tf_pairs}
        found = BagTopics(ScanStream(), {t: PoseStream() for t in pose_topics}, {}, {}, types)
        for pair in tf_pairs:
            found.transforms[(frame(pair[0]), frame(pair[1]))] = PoseStream()
        connections = [c for c in reader.connections if c.topic in types]
        for topic, msg in messages(reader, bag, connections):
            if topic == scan_topic:
                scans = found.scans
                _check_scan(bag, topic, len(scans.stamps), msg, scans.geometry)
                scans.geometry = scans.geometry or _scan_geometry(msg)
                scans.stamps.append(stamp_of(msg.header))
                scans.ranges.append(np.asarray(msg.ranges, dtype=np.float32))
            elif topic in found.poses:
                stamp, pose, cov = estimate_of(types[topic], msg)
                stream = found.poses[topic]
                stream.stamps.append(stamp)
                stream.poses.append(pose)
                stream.covs.append(cov)
            else:
                _add_transforms(found, msg, wanted, static=topic == tf_static_topic)
    finally:
        close_bag(reader)
    return found


def _add_transforms(found: BagTopics, msg: Any, wanted: dict[str, str], static: bool) -> None:
    for tr in msg.transforms:
        parent, child = frame(tr.header.frame_id), frame(tr.child_frame_id)
        t, q = tr.transform.translation, tr.transform.rotation
        pose = (float(t.x), float(t.y), quaternion_yaw(q.x, q.y, q.z, q.w))
        if static:
            found.static[(parent, child)] = pose
            continue
        if wanted.get(parent) == child:
            stream = found.transforms[(parent, child)]
            stream.stamps.append(stamp_of(tr.header))
            stream.poses.append(pose)
            stream.covs.append(np.full(6, np.nan))
        spread = found.dynamic.get((parent, child))
        if spread is None:
            found.dynamic[(parent, child)] = TfSpread(pose)
        else:
            spread.add(pose)
