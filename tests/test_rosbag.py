"""ROS bags as a source (``jaxcls.world.rosbag``): bags written here with ``rosbags`` itself from a rendered
scene read back to the same frames and poses (TF chains with static and interpolated links, a PoseStamped
topic, 16UC1 and big-endian 32FC1 depth), and bad bags refused with errors naming the topic or link."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxcls.cli import main
from jaxcls.config import load_config
from jaxcls.world import dataset, recording
from jaxcls.world.rosbag import BagConfig, BagError, PoseSource, read_bag

SMALL = ["camera.width=64", "camera.height=48", "camera.fx=52.5", "camera.fy=52.5", "camera.cx=31.5",
         "camera.cy=23.5", "viewpoints.count=4", "num_scenes=1", "batch_size=4", "backend=mujoco"]
T0 = 100.0  # s: the first frame's stamp; frames every 0.5 s


@pytest.fixture(scope="module")
def views(tmp_path_factory) -> dataset.SceneViews:
    tmp = tmp_path_factory.mktemp("rosbag")
    config = load_config(dataset.DatasetConfig, "configs/synthetic.yaml", [*SMALL, f"out_dir={tmp / 'ds'}"])
    return dataset.SceneViews.load(dataset.scene_file(dataset.build_dataset(config, show_progress=False), 0))


def _turned(T: np.ndarray, angle: float, shift: float) -> np.ndarray:
    """``T`` turned by ``angle`` about its z axis and moved by ``shift`` along world x."""
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", angle).as_matrix()
    out[0, 3] += shift
    return out


def write_bag(path: Path, views: dataset.SceneViews, *, float_depth: bool = False, poses: str = "tf",
              skew: float = 0.004, topics: tuple[str, ...] = ("depth", "info", "poses")) -> None:
    """A ROS 2 bag of ``views``: CameraInfo, depth images (16UC1 mm, or big-endian 32FC1 m with NaN holes) and
    the camera's poses, either TF (world -> tool dynamic, sampled ``skew`` s before and after each frame
    symmetrically about the true pose; tool -> camera_optical static) or a PoseStamped topic."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    k = views.intrinsics

    def header(sec: float, frame: str):
        ns = round(sec * 1e9)
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame)

    def transform(parent: str, child: str, T: np.ndarray, sec: float):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        return t["geometry_msgs/msg/TransformStamped"](
            header=header(sec, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))

    T_tool_cam = np.eye(4)
    T_tool_cam[:3, :3] = Rotation.from_euler("xyz", [0.1, -0.2, 0.3]).as_matrix()
    T_tool_cam[:3, 3] = [0.02, -0.01, 0.05]
    with Writer(path, version=8) as writer:
        def connection(topic: str, msgtype: str):
            return writer.add_connection(topic, msgtype, typestore=ts)

        def put(conn, msg, sec: float) -> None:
            writer.write(conn, round(sec * 1e9), ts.serialize_cdr(msg, conn.msgtype))

        if "info" in topics:
            info = t["sensor_msgs/msg/CameraInfo"](
                header=header(T0, "camera_optical"), height=k.height, width=k.width, distortion_model="plumb_bob",
                d=np.zeros(5), k=np.array([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1.0]), r=np.eye(3).reshape(-1),
                p=np.array([k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0,
                roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            put(connection("/camera/depth/camera_info", info.__msgtype__), info, T0)
        if "poses" in topics and poses == "tf":
            static = connection("/tf_static", "tf2_msgs/msg/TFMessage")
            dynamic = connection("/tf", "tf2_msgs/msg/TFMessage")
            put(static, t["tf2_msgs/msg/TFMessage"](transforms=[transform("tool", "camera_optical", T_tool_cam, T0)]),
                T0 - 1)
        elif "poses" in topics:
            pose_topic = connection("/camera/pose", "geometry_msgs/msg/PoseStamped")
        images = connection("/camera/depth/image_rect_raw", "sensor_msgs/msg/Image") if "depth" in topics else None
        for i, (depth, T_wc) in enumerate(zip(views.depth, views.T_wc, strict=True)):
            sec = T0 + 0.5 * i
            if "poses" in topics and poses == "tf":
                T_world_tool = T_wc @ np.linalg.inv(T_tool_cam)
                for s in (-1, 1):  # symmetric about the truth: the interpolation at the frame's time gives it back
                    sample = _turned(T_world_tool, s * 0.01, s * 0.001)
                    put(dynamic, t["tf2_msgs/msg/TFMessage"](transforms=[transform("world", "tool", sample,
                                                                                   sec + s * skew)]), sec + s * skew)
            elif "poses" in topics:
                q = Rotation.from_matrix(T_wc[:3, :3]).as_quat()
                pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=T_wc[0, 3], y=T_wc[1, 3],
                                                                                          z=T_wc[2, 3]),
                                                   orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                                  w=q[3]))
                put(pose_topic, t["geometry_msgs/msg/PoseStamped"](header=header(sec, "world"), pose=pose), sec)
            if images is None:
                continue
            if float_depth:
                pixels = np.where(depth > 0, depth, np.nan).astype(">f4")
                encoding, bigendian = "32FC1", 1
            else:
                pixels = np.round(depth * 1000).astype("<u2")
                encoding, bigendian = "16UC1", 0
            step = pixels.shape[1] * pixels.itemsize + 8  # padded rows, as some drivers send
            data = np.zeros((k.height, step), np.uint8)
            data[:, :pixels.shape[1] * pixels.itemsize] = pixels.view(np.uint8).reshape(k.height, -1)
            image = t["sensor_msgs/msg/Image"](header=header(sec, "camera_optical"), height=k.height, width=k.width,
                                               encoding=encoding, is_bigendian=bigendian, step=step,
                                               data=data.reshape(-1))
            put(images, image, sec)


def test_a_bag_with_tf_reads_back_the_frames_and_poses(views, tmp_path):
    write_bag(tmp_path / "bag", views)
    rec = read_bag(tmp_path / "bag")
    assert rec.intrinsics == views.intrinsics
    np.testing.assert_array_equal(rec.depth, recording.quantise_depth(views.depth))
    np.testing.assert_allclose(rec.T_wc, views.T_wc, atol=1e-9)  # the TF chain, interpolated at each frame


def test_a_pose_topic_and_float_depth(views, tmp_path):
    write_bag(tmp_path / "bag", views, float_depth=True, poses="topic")
    rec = read_bag(tmp_path / "bag", BagConfig(poses=PoseSource.topic))
    np.testing.assert_array_equal(rec.depth, views.depth)  # NaN holes back to 0, big-endian floats read
    np.testing.assert_allclose(rec.T_wc, views.T_wc, atol=1e-9)


def test_export_and_run_read_a_bag(views, tmp_path):
    from jaxcls.commands.run import RunConfig, open_source

    write_bag(tmp_path / "bag", views)
    assert main(["export", str(tmp_path / "bag"), str(tmp_path / "rec")]) == 0
    rec = recording.read_recording(tmp_path / "rec")
    np.testing.assert_array_equal(rec.depth, recording.quantise_depth(views.depth))
    np.testing.assert_allclose(rec.T_wc, views.T_wc, atol=1e-6)  # (the recording's text poses)
    source = open_source(load_config(RunConfig, None, [f"source={tmp_path / 'bag'}"]), None)
    np.testing.assert_allclose(source.viewpoints, views.T_wc, atol=1e-9)
    assert source.scene is None and source.intrinsics == views.intrinsics


def test_bad_bags_are_refused_naming_the_topic_or_link(views, tmp_path):
    write_bag(tmp_path / "no_info", views, topics=("depth", "poses"))
    with pytest.raises(BagError, match="no topic '/camera/depth/camera_info'"):
        read_bag(tmp_path / "no_info")
    write_bag(tmp_path / "no_poses", views, topics=("depth", "info"))
    with pytest.raises(BagError, match="no /tf or /tf_static"):
        read_bag(tmp_path / "no_poses")
    with pytest.raises(BagError, match="no topic '/camera/pose'"):
        read_bag(tmp_path / "no_poses", BagConfig(poses=PoseSource.topic))
    write_bag(tmp_path / "late", views, skew=0.05)  # TF sampled 50 ms from each frame: beyond 20 ms
    with pytest.raises(BagError, match=r"TF link world -> tool: no pose within max_time_offset 0\.02 s of depth "
                                       r"image 0"):
        read_bag(tmp_path / "late")
    assert read_bag(tmp_path / "late", BagConfig(max_time_offset=0.06)).num_frames == 4
    with pytest.raises(BagError, match="no path from 'map'"):
        read_bag(tmp_path / "late", BagConfig(world_frame="map", max_time_offset=0.06))
    with pytest.raises(BagError, match="not a ROS bag"):
        read_bag(tmp_path)
    assert main(["export", str(tmp_path / "no_info"), str(tmp_path / "rec")]) == 2
    assert not (tmp_path / "rec").exists()
