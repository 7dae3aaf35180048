"""Recording folders: exact round trips, a real 16-bit PNG on disk, and clear errors for every bad input."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from jaxcls.geometry import Intrinsics
from jaxcls.world import recording as rec
from jaxcls.world.recording import (
    Recording,
    RecordingError,
    quantise_depth,
    read_recording,
    write_recording,
)

INTRINSICS = Intrinsics(width=40, height=30, fx=37.5, fy=38.25, cx=19.25, cy=14.75)
SCENE = {"objects": [{"class": "mug", "pose": [0.1, -0.2, 0.0, 0.3]}], "seed": 7}


def make_recording(seed: int = 0, frames: int = 3) -> Recording:
    """A tilted plane with holes seen from random rigid poses: depth values that need every bit of a mm."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[: INTRINSICS.height, : INTRINSICS.width]
    depth = np.empty((frames, INTRINSICS.height, INTRINSICS.width), np.float32)
    for t in range(frames):
        plane = 0.6 + 0.4 * t + 0.013 * u + 0.007 * v + rng.normal(0, 0.002, u.shape)
        depth[t] = np.where(rng.random(u.shape) < 0.15, 0.0, plane)
    T = np.tile(np.eye(4), (frames, 1, 1))
    T[:, :3, :3] = Rotation.random(frames, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.normal(0, 1.0, (frames, 3))
    return Recording(depth=depth, T_wc=T, intrinsics=INTRINSICS, table_height=0.7312345678901234,
                     scene=SCENE)


@pytest.fixture
def written(tmp_path: Path) -> Path:
    return write_recording(tmp_path / "rec", make_recording())


def png_ihdr(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) parsed here, independently of the module under test."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return (int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), data[24], data[25])


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------------ round trip

def test_round_trip_exact(tmp_path: Path) -> None:
    original = make_recording()
    folder = write_recording(tmp_path / "rec", original)
    back = read_recording(folder)
    assert back.depth.dtype == np.float32 and back.T_wc.dtype == np.float64
    np.testing.assert_array_equal(back.depth, quantise_depth(original.depth))
    np.testing.assert_array_equal(back.T_wc, original.T_wc)  # bit-exact float64
    assert back.intrinsics == original.intrinsics
    assert back.table_height == original.table_height
    assert back.scene == SCENE
    assert np.all(back.depth[original.depth == 0] == 0)  # holes stay holes


def test_rewrite_is_byte_identical(tmp_path: Path, written: Path) -> None:
    again = write_recording(tmp_path / "again", read_recording(written))
    assert tree(again) == tree(written)
    assert len(tree(written)) == 3 + 3  # meta, intrinsics, poses + 3 PNGs


def test_no_scene_and_zero_frames(tmp_path: Path) -> None:
    empty = Recording(depth=np.zeros((0, 30, 40)), T_wc=np.zeros((0, 4, 4)), intrinsics=INTRINSICS,
                      table_height=0.0)
    back = read_recording(write_recording(tmp_path / "e", empty))
    assert back.depth.shape == (0, 30, 40) and back.T_wc.shape == (0, 4, 4) and back.scene is None
    assert "scene" not in json.loads((tmp_path / "e" / "meta.json").read_text())


def test_meta_contents(written: Path) -> None:
    meta = json.loads((written / "meta.json").read_text())
    assert meta["format"] == "jaxcls-recording" and meta["version"] == 1
    assert meta["depth_scale"] == 1000.0 and meta["frames"] == 3
    lines = [x for x in (written / "poses.txt").read_text().splitlines() if not x.startswith("#")]
    assert [int(x.split()[0]) for x in lines] == [0, 1, 2]


def test_png_is_16bit_greyscale(written: Path) -> None:
    original = make_recording()
    for t in range(3):
        path = written / "depth" / f"{t:06d}.png"
        assert png_ihdr(path) == (40, 30, 16, 0)  # bit depth 16, colour type 0 (greyscale)
        with Image.open(path) as im:
            assert im.format == "PNG" and im.mode in ("I;16", "I;16B") and im.size == (40, 30)
            raw = np.asarray(im)
        expected_mm = np.rint(np.asarray(original.depth[t], np.float64) * 1000).astype(np.uint16)
        np.testing.assert_array_equal(raw, expected_mm)  # Pillow reads back bit-exactly, in mm


def test_depth_scale_other_than_mm(written: Path) -> None:
    """A TUM-style recording (5000 units per metre) reads in metres."""
    meta = json.loads((written / "meta.json").read_text())
    meta["depth_scale"] = 5000.0
    (written / "meta.json").write_text(json.dumps(meta))
    raw = rec.depth_to_raw(make_recording().depth)
    np.testing.assert_array_equal(read_recording(written).depth, rec.raw_to_depth(raw, 5000.0))
    np.testing.assert_allclose(read_recording(written).depth, raw / 5000.0, rtol=1e-7)


# ---------------------------------------------------------------------------------------- quantisation

def test_quantisation_error_within_half_mm() -> None:
    d = np.random.default_rng(1).uniform(0, 65.5349, 200_000)
    raw = rec.depth_to_raw(d)
    assert raw.dtype == np.uint16
    assert np.max(np.abs(raw - d * 1000)) <= 0.5
    q = quantise_depth(d)
    assert q.dtype == np.float32
    assert np.max(np.abs(q - d)) <= 0.5e-3 + 65.535 * 2.0**-24  # plus one f32 rounding of the result
    np.testing.assert_array_equal(quantise_depth(q), q)  # idempotent: re-export loses nothing more


def test_non_finite_and_negative_become_zero_with_count() -> None:
    d = np.array([1.0, np.nan, np.inf, -np.inf, -0.5, 2.0])
    with pytest.warns(RuntimeWarning, match="4 NaN/inf/negative"):
        q = quantise_depth(d)
    np.testing.assert_array_equal(q, np.array([1.0, 0, 0, 0, 0, 2.0], np.float32))


def test_far_depth_is_clipped_with_warning() -> None:
    with pytest.warns(RuntimeWarning, match="1 depth value.*clipped"):
        q = quantise_depth(np.array([70.0, 65.535]))
    np.testing.assert_array_equal(q, np.float32([65.535, 65.535]))


def test_write_tolerates_non_finite_depth(tmp_path: Path) -> None:
    r = make_recording()
    depth = r.depth.copy()
    depth[0, 0, :3] = [np.nan, np.inf, -1.0]
    with pytest.warns(RuntimeWarning, match="3 NaN/inf/negative"):
        folder = write_recording(tmp_path / "r", Recording(depth, r.T_wc, INTRINSICS, 0.0))
    back = read_recording(folder)
    assert np.all(back.depth[0, 0, :3] == 0) and np.all(np.isfinite(back.depth))


def test_clean_depth_writes_without_warning(tmp_path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_recording(tmp_path / "r", make_recording())


# ------------------------------------------------------------------------------------------ atomicity

def test_interrupted_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = rec._write_png16

    def fail_on_third(path: Path, raw: np.ndarray) -> None:
        if path.name == "000002.png":
            raise KeyboardInterrupt
        real(path, raw)

    monkeypatch.setattr(rec, "_write_png16", fail_on_third)
    with pytest.raises(KeyboardInterrupt):
        write_recording(tmp_path / "rec", make_recording())
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temp folder


def test_interrupted_overwrite_keeps_old(tmp_path: Path, written: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    before = tree(written)
    monkeypatch.setattr(rec, "_write_png16", lambda path, raw: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError, match="disk full"):
        write_recording(written, make_recording(seed=5), overwrite=True)
    assert tree(written) == before and [p.name for p in tmp_path.iterdir()] == ["rec"]


def test_overwrite_rules(tmp_path: Path, written: Path) -> None:
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_recording(written, make_recording(seed=1))
    write_recording(written, make_recording(seed=1, frames=2), overwrite=True)
    assert read_recording(written).depth.shape[0] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.tex").write_text("x")
    with pytest.raises(FileExistsError, match="not a jaxcls-recording"):
        write_recording(precious, make_recording(), overwrite=True)
    assert (precious / "thesis.tex").exists()


# ------------------------------------------------------------------------------------------ validation

def edit_json(path: Path, **changes: object) -> None:
    data = json.loads(path.read_text())
    for key, value in changes.items():
        if value is ...:
            del data[key]
        else:
            data[key] = value
    path.write_text(json.dumps(data))


def edit_pose_line(folder: Path, frame: int, new: str) -> None:
    path = folder / "poses.txt"
    lines = path.read_text().splitlines(keepends=True)
    lines[1 + frame] = new + "\n"  # line 1 is the header comment
    path.write_text("".join(lines))


@pytest.mark.parametrize("name", ["meta.json", "intrinsics.json", "poses.txt"])
def test_missing_file(written: Path, name: str) -> None:
    (written / name).unlink()
    with pytest.raises(RecordingError, match=rf"{name}: missing"):
        read_recording(written)


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nope"):
        read_recording(tmp_path / "nope")


def test_wrong_format(written: Path) -> None:
    edit_json(written / "meta.json", format="something-else")
    with pytest.raises(RecordingError, match=r"meta\.json: key 'format' is 'something-else'"):
        read_recording(written)


def test_wrong_version(written: Path) -> None:
    edit_json(written / "meta.json", version=2)
    with pytest.raises(RecordingError, match=r"meta\.json: key 'version'"):
        read_recording(written)


def test_invalid_json(written: Path) -> None:
    (written / "intrinsics.json").write_text("{not json")
    with pytest.raises(RecordingError, match=r"intrinsics\.json: invalid JSON"):
        read_recording(written)


@pytest.mark.parametrize("key", ["format", "version", "table_height", "depth_scale", "frames"])
def test_missing_meta_key(written: Path, key: str) -> None:
    edit_json(written / "meta.json", **{key: ...})
    with pytest.raises(RecordingError, match=rf"meta\.json: missing key '{key}'"):
        read_recording(written)


@pytest.mark.parametrize("key", ["width", "height", "fx", "fy", "cx", "cy"])
def test_missing_intrinsics_key(written: Path, key: str) -> None:
    edit_json(written / "intrinsics.json", **{key: ...})
    with pytest.raises(RecordingError, match=rf"intrinsics\.json: missing key '{key}'"):
        read_recording(written)


@pytest.mark.parametrize(("file", "key", "value"), [
    ("meta.json", "frames", 2.5), ("meta.json", "frames", True), ("meta.json", "table_height", "high"),
    ("meta.json", "depth_scale", 0), ("intrinsics.json", "width", 40.0), ("intrinsics.json", "fx", -1),
])
def test_bad_values(written: Path, file: str, key: str, value: object) -> None:
    edit_json(written / file, **{key: value})
    with pytest.raises(RecordingError, match=rf"{file}: key '{key}'|{file}: focal"):
        read_recording(written)


def test_non_rigid_pose_names_frame(written: Path) -> None:
    T = make_recording().T_wc[1].copy()
    T[:3, :3] *= 1.1  # a scaled rotation
    edit_pose_line(written, 1, " ".join(["1", *map(repr, T.reshape(16).tolist())]))
    with pytest.raises(RecordingError, match=r"poses\.txt line 3: pose of frame 1 is not a rigid"):
        read_recording(written)


def test_nan_pose(written: Path) -> None:
    edit_pose_line(written, 2, "2" + " nan" * 16)
    with pytest.raises(RecordingError, match=r"poses\.txt line 4: pose of frame 2"):
        read_recording(written)


@pytest.mark.parametrize(("line", "message"), [
    ("1 1 0 0", "expected a frame index and 16 numbers"),
    ("5 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "frame index 5, expected 1"),
    ("1 1 0 0 x 0 1 0 0 0 0 1 0 0 0 0 1", "cannot parse"),
])
def test_malformed_pose_line(written: Path, line: str, message: str) -> None:
    edit_pose_line(written, 1, line)
    with pytest.raises(RecordingError, match=rf"poses\.txt line 3: {message}"):
        read_recording(written)


def test_pose_count_disagrees_with_meta(written: Path) -> None:
    edit_json(written / "meta.json", frames=4)
    with pytest.raises(RecordingError, match=r"poses\.txt: 3 poses but meta\.json says frames = 4"):
        read_recording(written)


def test_frame_count_disagrees_with_pngs(written: Path) -> None:
    (written / "depth" / "000003.png").write_bytes((written / "depth" / "000000.png").read_bytes())
    with pytest.raises(RecordingError, match=r"depth: 4 PNGs but meta\.json says frames = 3"):
        read_recording(written)


def test_missing_depth_frame(written: Path) -> None:
    (written / "depth" / "000001.png").unlink()
    with pytest.raises(RecordingError, match=r"000001\.png: missing depth frame 1"):
        read_recording(written)


def test_8bit_png(written: Path) -> None:
    Image.fromarray(np.zeros((30, 40), np.uint8)).save(written / "depth" / "000001.png")
    with pytest.raises(RecordingError, match=r"000001\.png: not a 16-bit greyscale PNG \(bit depth 8"):
        read_recording(written)


def test_wrong_size_png(written: Path) -> None:
    rec._write_png16(written / "depth" / "000002.png", np.zeros((30, 41), np.uint16))
    with pytest.raises(RecordingError, match=r"000002\.png: size 41x30 does not match intrinsics"):
        read_recording(written)


def test_truncated_png(written: Path) -> None:
    path = written / "depth" / "000001.png"
    path.write_bytes(path.read_bytes()[:60])
    with pytest.raises(RecordingError, match=r"000001\.png: cannot decode"):
        read_recording(written)


def test_not_a_png(written: Path) -> None:
    (written / "depth" / "000000.png").write_bytes(b"hello")
    with pytest.raises(RecordingError, match=r"000000\.png: not a PNG"):
        read_recording(written)


# --------------------------------------------------------------------------------- Recording checks

def test_recording_validates_itself() -> None:
    r = make_recording()
    with pytest.raises(ValueError, match="intrinsics"):
        Recording(r.depth[:, :, :-1], r.T_wc, INTRINSICS, 0.0)
    with pytest.raises(ValueError, match="T_wc must be"):
        Recording(r.depth, r.T_wc[:2], INTRINSICS, 0.0)
    bad = r.T_wc.copy()
    bad[2, 3, 0] = 1.0
    with pytest.raises(ValueError, match=r"frame\(s\) \[2\]"):
        Recording(r.depth, bad, INTRINSICS, 0.0)
    with pytest.raises(ValueError, match="table_height"):
        Recording(r.depth, r.T_wc, INTRINSICS, math.nan)


def test_kinect_intrinsics_round_trip(tmp_path: Path) -> None:
    """The default sensor's derived float focal length survives JSON exactly."""
    k = Intrinsics.kinect_v1(scale=0.1)
    r = Recording(np.full((1, k.height, k.width), 1.234), np.eye(4)[None], k, 0.0)
    assert read_recording(write_recording(tmp_path / "k", r)).intrinsics == k
