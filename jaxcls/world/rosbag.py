"""A real robot's ROS bag as a recorded sequence: depth images with the camera's poses, read without a ROS
install by ``rosbags`` (ROS 2 bag folders, tested here with bags ``rosbags`` writes; ROS 1 ``.bag`` files go
through the same reader, untested).

What is read (topics configurable, ``BagConfig``):
- depth images (``sensor_msgs/Image``), ``16UC1`` in millimetres or ``32FC1`` in metres, either byte order;
  NaN, inf and negative depths become 0 (no return);
- the intrinsics from a ``sensor_msgs/CameraInfo`` topic (its first message; fx, fy, cx, cy from ``k``);
- each frame's camera pose (camera-to-world, ROS's optical frame: x right, y down, z forward, the OpenCV
  convention of this project) either from TF (``/tf`` and ``/tf_static``: the chain of transforms from
  ``world_frame`` down to the camera frame, each dynamic link taken at the frame's time) or from a
  ``geometry_msgs/PoseStamped`` topic (the optical frame's pose in the world).

Time synchronisation: a frame's time is its header stamp; a pose sample series (a PoseStamped topic, or each
dynamic TF link) is interpolated linearly (translation) and spherically (rotation) between the two samples
around it when both lie within ``max_time_offset`` of the frame; else the nearest sample within that offset
is used; else ``BagError`` names the topic (or TF link) and the frame's time.

    recording = read_bag("runs/robot_bag", BagConfig(depth_topic="/camera/depth/image_rect_raw"))
    jaxcls run source=runs/robot_bag bag.world_frame=base_link      # (jaxcls.commands.run)
    jaxcls export runs/robot_bag runs/robot_recording                # the recording folder format
"""

from __future__ import annotations

import dataclasses
import enum
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics
from jaxcls.world import recording


class PoseSource(enum.StrEnum):
    """Where a bag's camera poses come from: ``tf`` (the TF tree) or ``topic`` (a PoseStamped topic)."""

    tf = "tf"
    topic = "topic"


@dataclasses.dataclass(frozen=True)
class BagConfig:
    """``bag:`` of ``jaxcls run``: which topics and frames of a ROS bag make the recorded sequence."""

    depth_topic: str = "/camera/depth/image_rect_raw"  # sensor_msgs/Image, 16UC1 (mm) or 32FC1 (m)
    camera_info_topic: str = "/camera/depth/camera_info"  # sensor_msgs/CameraInfo: the intrinsics
    poses: PoseSource = PoseSource.tf
    pose_topic: str = "/camera/pose"  # poses: topic: geometry_msgs/PoseStamped, the optical frame in the world
    world_frame: str = "world"  # poses: tf: the root the camera's pose is taken in
    camera_frame: str = ""  # poses: tf: the camera's optical frame ("": the depth images' frame_id)
    max_time_offset: float = bounded(0.02, gt=0.0)  # s between a frame and the pose samples it uses
    table_height: float = 0.0  # world z of the table plane [m]

    def __post_init__(self) -> None:
        check_bounds(self, "bag.")


class BagError(ValueError):
    """A bag that cannot be read as configured: names the bag, the topic or TF link, and what is wrong."""


def is_bag(path: str | Path) -> bool:
    """A ROS 2 bag folder (``metadata.yaml``) or a ROS 1 ``.bag`` file."""
    path = Path(path)
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or (path.is_file() and path.suffix == ".bag")


def _stamp(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _matrix(translation: Any, rotation: Any) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w]).as_matrix()
    T[:3, 3] = [translation.x, translation.y, translation.z]
    return T


def _depth_image(msg: Any, where: str) -> np.ndarray:
    """[H, W] f32 metres of a depth ``sensor_msgs/Image`` (0 where there is no return)."""
    kinds = {"16UC1": (np.uint16, 1e-3), "mono16": (np.uint16, 1e-3), "32FC1": (np.float32, 1.0)}
    if msg.encoding not in kinds:
        raise BagError(f"{where}: encoding {msg.encoding!r} is not a depth image (16UC1 in mm or 32FC1 in m)")
    dtype, scale = kinds[msg.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = msg.width * dtype.itemsize
    data = np.asarray(msg.data, np.uint8)
    if msg.step < row or data.size < msg.step * msg.height:
        raise BagError(f"{where}: {data.size} bytes with step {msg.step} do not hold {msg.height} rows of {msg.width} "
                       f"{msg.encoding} pixels")
    rows = data[:msg.step * msg.height].reshape(msg.height, msg.step)[:, :row]
    depth = np.ascontiguousarray(rows).view(dtype).astype(np.float64) * scale
    return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)


class _Series:
    """Pose samples of one topic or TF link over time: the pose at a time, interpolated or nearest."""

    def __init__(self, name: str, times: list[float], poses: list[np.ndarray]) -> None:
        order = np.argsort(times, kind="stable")
        self.name, self.times = name, np.asarray(times, np.float64)[order]
        self.poses = np.asarray(poses, np.float64)[order]

    def at(self, t: float, tolerance: float, frame: str) -> np.ndarray:
        i = int(np.searchsorted(self.times, t))
        before, after = (i - 1 if i > 0 else None), (i if i < len(self.times) else None)
        near = [j for j in (before, after) if j is not None and abs(self.times[j] - t) <= tolerance]
        if not near:
            closest = min((j for j in (before, after) if j is not None), key=lambda j: abs(self.times[j] - t))
            raise BagError(f"{self.name}: no pose within max_time_offset {tolerance:g} s of {frame} at t = {t:.6f} s "
                           f"(the nearest at {self.times[closest]:.6f} s)")
        if len(near) == 1 or self.times[after] == self.times[before]:
            return self.poses[near[0]]
        a, b = self.poses[before], self.poses[after]
        w = (t - self.times[before]) / (self.times[after] - self.times[before])
        T = np.eye(4)
        T[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))([w]).as_matrix()[0]
        T[:3, 3] = (1 - w) * a[:3, 3] + w * b[:3, 3]
        return T


def _tf_chain(links: dict[tuple[str, str], _Series], static: dict[tuple[str, str], np.ndarray], world: str,
              camera: str, bag: Path) -> list[tuple[str, str]]:
    """The TF links (parent, child) from ``world`` down to ``camera``."""
    parent = {child: p for p, child in (*links, *static)}
    chain, frame = [], camera
    while frame != world:
        if frame not in parent:
            known = sorted({f for link in (*links, *static) for f in link})
            raise BagError(f"{bag}: TF has no path from {world!r} to {camera!r} (frame {frame!r} has no parent; "
                           f"frames in /tf and /tf_static: {known})")
        chain.append((parent[frame], frame))
        frame = parent[frame]
        if len(chain) > 64:
            raise BagError(f"{bag}: TF links from {camera!r} loop without reaching {world!r}")
    return chain[::-1]


def read_bag(path: str | Path, config: BagConfig | None = None) -> recording.Recording:
    """The bag at ``path`` (a ROS 2 bag folder or a ROS 1 ``.bag``) as a ``Recording``: one frame per depth
    image, in time order, with its camera pose and the CameraInfo's intrinsics. BagError names what is
    missing or out of sync."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    config = config or BagConfig()
    bag = Path(path)
    if not is_bag(bag):
        raise BagError(f"{bag}: not a ROS bag (a ROS 2 bag folder with metadata.yaml, or a ROS 1 .bag file)")
    wanted = {config.depth_topic, config.camera_info_topic}
    wanted |= {"/tf", "/tf_static"} if config.poses is PoseSource.tf else {config.pose_topic}
    frames: list[tuple[float, np.ndarray, str]] = []
    info = None
    pose_times: list[float] = []
    pose_values: list[np.ndarray] = []
    link_samples: dict[tuple[str, str], tuple[list, list]] = defaultdict(lambda: ([], []))
    static: dict[tuple[str, str], np.ndarray] = {}
    try:
        reader_context = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        with reader_context as reader:
            topics = {c.topic for c in reader.connections}
            missing = sorted(wanted - topics - {"/tf", "/tf_static"})
            if missing:
                raise BagError(f"{bag}: no topic {missing[0]!r} (the bag has {sorted(topics)}); set bag.* to its "
                               "topics")
            if config.poses is PoseSource.tf and not topics & {"/tf", "/tf_static"}:
                raise BagError(f"{bag}: no /tf or /tf_static topic for the camera poses (the bag has "
                               f"{sorted(topics)}); with a PoseStamped topic set bag.poses=topic bag.pose_topic=...")
            connections = [c for c in reader.connections if c.topic in wanted]
            for connection, _, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, connection.msgtype)
                topic = connection.topic
                if topic == config.depth_topic:
                    where = f"{bag}: {topic} message {len(frames)}"
                    frames.append((_stamp(msg.header), _depth_image(msg, where), msg.header.frame_id))
                elif topic == config.camera_info_topic and info is None:
                    info = msg
                elif topic == config.pose_topic and config.poses is PoseSource.topic:
                    pose_times.append(_stamp(msg.header))
                    pose_values.append(_matrix(msg.pose.position, msg.pose.orientation))
                elif topic in ("/tf", "/tf_static"):
                    for tf in msg.transforms:
                        link = (tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/"))
                        T = _matrix(tf.transform.translation, tf.transform.rotation)
                        if topic == "/tf_static":
                            static[link] = T
                        else:
                            link_samples[link][0].append(_stamp(tf.header))
                            link_samples[link][1].append(T)
    except BagError:
        raise
    except Exception as e:  # rosbags' own errors (a damaged bag, an unknown message type): name the bag
        raise BagError(f"{bag}: cannot read the bag ({type(e).__name__}: {e})") from e
    if not frames:
        raise BagError(f"{bag}: {config.depth_topic} holds no images")
    if info is None:
        raise BagError(f"{bag}: {config.camera_info_topic} holds no CameraInfo")
    k = np.asarray(info.k, np.float64).reshape(3, 3)
    try:
        intrinsics = Intrinsics(width=int(info.width), height=int(info.height), fx=float(k[0, 0]), fy=float(k[1, 1]),
                                cx=float(k[0, 2]), cy=float(k[1, 2]))
    except ValueError as e:
        raise BagError(f"{bag}: {config.camera_info_topic}: {e}") from None
    frames.sort(key=lambda f: f[0])
    for i, (t, depth, _) in enumerate(frames):
        if depth.shape != (intrinsics.height, intrinsics.width):
            raise BagError(f"{bag}: {config.depth_topic} image {i} (t = {t:.6f} s) is {depth.shape} (H, W), the "
                           f"CameraInfo says {(intrinsics.height, intrinsics.width)}")
    tolerance = config.max_time_offset
    if config.poses is PoseSource.topic:
        if not pose_times:
            raise BagError(f"{bag}: {config.pose_topic} holds no poses")
        series = _Series(f"{bag}: {config.pose_topic}", pose_times, pose_values)
        T_wc = [series.at(t, tolerance, f"depth image {i}") for i, (t, _, _) in enumerate(frames)]
    else:
        camera = config.camera_frame or frames[0][2].lstrip("/")
        links = {link: _Series(f"{bag}: TF link {link[0]} -> {link[1]}", *samples)
                 for link, samples in link_samples.items()}
        chain = _tf_chain(links, static, config.world_frame, camera, bag)
        T_wc = []
        for i, (t, _, _) in enumerate(frames):
            T = np.eye(4)
            for link in chain:
                T = T @ (static[link] if link in static else links[link].at(t, tolerance, f"depth image {i}"))
            T_wc.append(T)
    return recording.Recording(depth=np.stack([d for _, d, _ in frames]), T_wc=np.stack(T_wc),
                               intrinsics=intrinsics, table_height=config.table_height)


__all__ = ["BagConfig", "BagError", "PoseSource", "is_bag", "read_bag"]
