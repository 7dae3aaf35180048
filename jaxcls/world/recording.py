"""Recorded depth sequences on disk: the format a real robot's recording is read from and a rendered episode
is exported to, so that the same pipeline runs on both.

Folder layout (format ``jaxcls-recording``, version 1)::

    <folder>/
      meta.json          {"format": "jaxcls-recording", "version": 1, "table_height": 0.0,
                          "depth_scale": 1000.0, "frames": 3, "scene": {...}}     ("scene" optional)
      intrinsics.json    {"width": 640, "height": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5}
      poses.txt          # comment lines start with '#'; then one line per frame, in frame order:
                         0 r00 r01 r02 t0 r10 r11 r12 t1 r20 r21 r22 t2 0 0 0 1
                         1 ...
      depth/
        000000.png       16-bit greyscale PNG (uint16), raw value = depth [m] * depth_scale; 0 = no return
        000001.png
        000002.png

Meaning of each piece:

- ``meta.json``: ``format`` must be ``"jaxcls-recording"`` and ``version`` 1. ``table_height`` [m] is the
  world z of the table plane. ``depth_scale`` is raw PNG units per metre; this writer always uses 1000.0
  (millimetres, so 65.535 m at most), the reader accepts any positive value (e.g. 5000 for TUM-style
  recordings). ``frames`` is the number of frames T. ``scene`` is an optional JSON object carried along
  untouched (the description of a simulated scene, so that an exported episode can be scored later);
  tuples in it come back as lists.
- ``intrinsics.json``: the OpenCV pinhole of :class:`jaxcls.geometry.Intrinsics`, in pixels; ``width``
  and ``height`` are integers, every depth PNG must be ``width`` x ``height``.
- ``poses.txt``: per frame, the frame index then the 16 entries of the 4x4 camera-to-world transform
  ``T_wc`` (OpenCV camera: x right, y down, z forward; world z up; metres), row-major, separated by single
  spaces. Numbers are written with Python's ``repr`` (shortest string that reads back to the same
  float64), so poses round-trip exactly. Indices must run 0..T-1 in order; blank lines and lines starting
  with ``#`` are skipped. Every pose must pass :func:`jaxcls.geometry.is_rigid`.
- ``depth/NNNNNN.png``: z-depth (not ray length), six-digit zero-padded frame index, exactly one PNG per
  frame. Values are quantised by :func:`quantise_depth`, the one definition of what the PNG can hold.

Writing is atomic (``jaxcls.io.atomic_folder``): everything goes into a hidden sibling folder
(``.<name>.tmp-<random>``), ``meta.json`` last, which is renamed onto ``<folder>`` only when complete, so
an interrupted export leaves either no folder or the previous one. Files are not fsync'ed; after a power
loss the reader's full validation (every file parsed, every PNG decoded) still refuses a damaged folder
rather than reading it as complete.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from jaxcls import io
from jaxcls.geometry import Intrinsics, is_rigid

FORMAT = "jaxcls-recording"
VERSION = 1
DEPTH_SCALE = 1000.0  # raw PNG units per metre: millimetres
UINT16_MAX = 65535
META_KEYS = ("format", "version", "table_height", "depth_scale", "frames")
INTRINSICS_INT_KEYS = ("width", "height")
INTRINSICS_FLOAT_KEYS = ("fx", "fy", "cx", "cy")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_POSES_HEADER = ("# jaxcls-recording poses: frame index, then T_wc (camera-to-world, OpenCV camera, "
                 "metres) row-major, 16 numbers\n")


class RecordingError(ValueError):
    """A recording folder that does not follow the format; the message names the file (and key or line)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """A depth sequence with known camera poses, as recorded by a sensor or exported from a rendering.

    depth: [T, H, W] f32 z-depth in metres, 0 = no return (NaN/inf/negative are tolerated here and become 0
        on writing, with a warning). T_wc: [T, 4, 4] f64 rigid camera-to-world poses. table_height: world z
        of the table plane [m]. scene: optional JSON-serialisable scene description, carried along.
    Inputs are converted to f32 / f64; shapes and rigidity are checked so that a bad recording fails where
    it is built, not halfway through an export. ``eq=False``: array fields make ``==`` ambiguous.
    """

    depth: np.ndarray
    T_wc: np.ndarray
    intrinsics: Intrinsics
    table_height: float
    scene: dict | None = None

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth, np.float32)
        T_wc = np.asarray(self.T_wc, np.float64)
        object.__setattr__(self, "depth", depth)
        object.__setattr__(self, "T_wc", T_wc)
        object.__setattr__(self, "table_height", float(self.table_height))
        if depth.ndim != 3:
            raise ValueError(f"Recording: depth must be [T, H, W], got shape {depth.shape}")
        hw = (self.intrinsics.height, self.intrinsics.width)
        if depth.shape[1:] != hw:
            raise ValueError(f"Recording: depth frames are {depth.shape[1:]} (H, W) but intrinsics say {hw}")
        if T_wc.shape != (depth.shape[0], 4, 4):
            raise ValueError(f"Recording: T_wc must be [{depth.shape[0]}, 4, 4] to match depth, "
                             f"got {T_wc.shape}")
        bad = np.flatnonzero(~is_rigid(T_wc))
        if bad.size:
            raise ValueError(f"Recording: T_wc of frame(s) {bad.tolist()} not a rigid transform")
        if not math.isfinite(self.table_height):
            raise ValueError(f"Recording: table_height must be finite, got {self.table_height}")
        if self.scene is not None and not isinstance(self.scene, dict):
            raise ValueError(f"Recording: scene must be a dict or None, got {type(self.scene).__name__}")

    @property
    def num_frames(self) -> int:
        return int(self.depth.shape[0])


# ---------------------------------------------------------------------------------------------- depth

def depth_to_raw(depth_m: np.ndarray, depth_scale: float = DEPTH_SCALE) -> np.ndarray:
    """[...] uint16 raw PNG values of ``depth_m: [...]`` metres: round(depth * scale), clipped to uint16.

    NaN, +-inf and negative depth become 0 (no return) and are counted in one RuntimeWarning rather than
    crashing an export over a few bad pixels; finite depth beyond 65535 / scale is clipped (also warned).
    Rounding is half-to-even in float64, so the error is <= 0.5 raw units (0.5 mm at the default scale).
    """
    d = np.asarray(depth_m, np.float64) * depth_scale
    invalid = ~np.isfinite(d) | (d < 0)
    d = np.where(invalid, 0.0, d)
    d = np.rint(d)
    too_far = d > UINT16_MAX  # what rounds to UINT16_MAX is still held within 0.5 units
    n_invalid, n_far = int(invalid.sum()), int(too_far.sum())
    if n_invalid:
        warnings.warn(f"quantise_depth: {n_invalid} NaN/inf/negative depth value(s) set to 0 (no return)",
                      RuntimeWarning, stacklevel=2)
    if n_far:
        warnings.warn(f"quantise_depth: {n_far} depth value(s) beyond {UINT16_MAX / depth_scale} m clipped",
                      RuntimeWarning, stacklevel=2)
    return np.minimum(d, UINT16_MAX).astype(np.uint16)


def raw_to_depth(raw: np.ndarray, depth_scale: float = DEPTH_SCALE) -> np.ndarray:
    """[...] f32 metres of raw PNG values ``raw: [...]``; 0 stays 0 (no return)."""
    return (np.asarray(raw, np.float64) / depth_scale).astype(np.float32)


def quantise_depth(depth_m: np.ndarray, depth_scale: float = DEPTH_SCALE) -> np.ndarray:
    """[...] f32 metres: exactly the depth a written-then-read recording holds for ``depth_m: [...]`` metres.

    Rounded to 1 / depth_scale m (mm by default), clipped to the uint16 range, NaN/inf/negative -> 0 (see
    :func:`depth_to_raw`). Idempotent: quantise_depth(quantise_depth(d)) == quantise_depth(d).
    """
    return raw_to_depth(depth_to_raw(depth_m, depth_scale), depth_scale)


def _write_png16(path: Path, raw: np.ndarray) -> None:
    """Write ``raw: [H, W] uint16`` as a 16-bit greyscale PNG; frombytes makes the mode explicit."""
    h, w = raw.shape
    Image.frombytes("I;16", (w, h), np.ascontiguousarray(raw, "<u2").tobytes()).save(path, format="PNG")


def png_header(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) from a PNG's IHDR chunk; the ground truth for '16-bit grey'.

    Pillow's mode for 16-bit PNGs has changed across versions ("I" vs "I;16"), the header has not.
    """
    with open(path, "rb") as f:
        head = f.read(29)
    if len(head) < 29 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise RecordingError(f"{path}: not a PNG file")
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return width, height, head[24], head[25]


def _read_png16(path: Path, intrinsics: Intrinsics) -> np.ndarray:
    """[H, W] uint16 raw values of one depth PNG, after checking bit depth, colour type and size."""
    width, height, bit_depth, colour_type = png_header(path)
    if bit_depth != 16 or colour_type != 0:
        raise RecordingError(f"{path}: not a 16-bit greyscale PNG (bit depth {bit_depth}, "
                             f"colour type {colour_type}); depth must be uint16")
    if (width, height) != (intrinsics.width, intrinsics.height):
        raise RecordingError(f"{path}: size {width}x{height} does not match intrinsics.json "
                             f"{intrinsics.width}x{intrinsics.height}")
    try:
        with Image.open(path) as im:
            arr = np.asarray(im)
    except Exception as e:  # truncated or corrupt data: name the file
        raise RecordingError(f"{path}: cannot decode PNG ({e})") from e
    if arr.shape != (height, width) or arr.min(initial=0) < 0 or arr.max(initial=0) > UINT16_MAX:
        raise RecordingError(f"{path}: decoded to shape {arr.shape}, dtype {arr.dtype}; expected uint16 "
                             f"[{height}, {width}]")
    return arr.astype(np.uint16)


# ---------------------------------------------------------------------------------------------- write

def _is_recording_or_empty(folder: Path) -> bool:
    """Overwrite only what this module wrote (or an empty folder): never rmtree a user's arbitrary folder."""
    if not folder.is_dir():
        return False
    if not any(folder.iterdir()):
        return True
    try:
        return json.loads((folder / "meta.json").read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def _format_pose_line(index: int, T: np.ndarray) -> str:
    return " ".join([str(index), *(repr(float(x)) for x in T.reshape(16))]) + "\n"


def write_recording(folder: str | Path, recording: Recording, overwrite: bool = False) -> Path:
    """Write ``recording`` to ``folder`` atomically (``jaxcls.io.atomic_folder``); returns the path.

    ``overwrite`` replaces an existing recording (or empty folder) and refuses anything else, so a wrong
    path cannot delete unrelated data. Depth is quantised by :func:`quantise_depth` (warning about
    NaN/inf/negative values, which become 0). Output is deterministic: writing a recording read from disk
    reproduces byte-identical files.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder}: is a file, not a recording folder; choose another folder (overwrite "
                              "replaces a recording, never a file)")
    if folder.exists() or folder.is_symlink():
        if not overwrite:
            raise FileExistsError(f"{folder}: already exists (pass overwrite=True, or --overwrite to jaxcls "
                                  "export, to replace it)")
        if not _is_recording_or_empty(folder):
            raise FileExistsError(f"{folder}: exists and is not a {FORMAT} folder; refusing to overwrite")
    meta: dict[str, Any] = {"format": FORMAT, "version": VERSION, "table_height": recording.table_height,
                            "depth_scale": DEPTH_SCALE, "frames": recording.num_frames}
    if recording.scene is not None:
        meta["scene"] = recording.scene
    try:  # serialise before touching the disk: a non-JSON scene must not leave a temp folder behind
        meta_text = json.dumps(meta, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as e:
        raise ValueError(f"write_recording: meta.json (scene) is not strict JSON: {e}") from e
    k = recording.intrinsics
    intrinsics_text = json.dumps({"width": int(k.width), "height": int(k.height), "fx": float(k.fx),
                                  "fy": float(k.fy), "cx": float(k.cx), "cy": float(k.cy)}, indent=2) + "\n"
    raw = depth_to_raw(recording.depth)  # warns once for the whole sequence

    with io.atomic_folder(folder) as tmp:  # swapped onto folder only when complete
        (tmp / "intrinsics.json").write_text(intrinsics_text)
        with open(tmp / "poses.txt", "w") as f:
            f.write(_POSES_HEADER)
            f.writelines(_format_pose_line(i, T) for i, T in enumerate(recording.T_wc))
        (tmp / "depth").mkdir()
        for i in range(recording.num_frames):
            _write_png16(tmp / "depth" / f"{i:06d}.png", raw[i])
        (tmp / "meta.json").write_text(meta_text)  # last: a folder without it never reads as complete
    return folder


# ---------------------------------------------------------------------------------------------- read

def _load_json(path: Path) -> dict:
    return io.read_json_object(path, RecordingError)


def _number(path: Path, data: dict, key: str, integer: bool = False) -> float | int:
    """``data[key]`` as a finite number (an int when ``integer``); bools are not numbers here."""
    if key not in data:
        raise RecordingError(f"{path}: missing key '{key}'")
    value = data[key]
    kinds = int if integer else int | float
    ok = isinstance(value, kinds) and not isinstance(value, bool)
    if not ok or not math.isfinite(value):
        raise RecordingError(f"{path}: key '{key}' must be a finite {'integer' if integer else 'number'}, "
                             f"got {value!r}")
    return value


def _read_meta(path: Path) -> dict:
    meta = _load_json(path)
    for key in META_KEYS:
        if key not in meta:
            raise RecordingError(f"{path}: missing key '{key}'")
    if meta["format"] != FORMAT:
        raise RecordingError(f"{path}: key 'format' is {meta['format']!r}, expected {FORMAT!r}")
    if meta["version"] != VERSION or isinstance(meta["version"], bool):
        raise RecordingError(f"{path}: key 'version' is {meta['version']!r}; this reader knows {VERSION}")
    _number(path, meta, "table_height")
    if _number(path, meta, "depth_scale") <= 0:
        raise RecordingError(f"{path}: key 'depth_scale' must be > 0, got {meta['depth_scale']!r}")
    if _number(path, meta, "frames", integer=True) < 0:
        raise RecordingError(f"{path}: key 'frames' must be >= 0, got {meta['frames']!r}")
    if meta.get("scene") is not None and not isinstance(meta["scene"], dict):
        raise RecordingError(f"{path}: key 'scene' must be a JSON object or absent")
    return meta


def _read_intrinsics(path: Path) -> Intrinsics:
    data = _load_json(path)
    ints = {key: _number(path, data, key, integer=True) for key in INTRINSICS_INT_KEYS}
    for key, value in ints.items():
        if value <= 0:
            raise RecordingError(f"{path}: key '{key}' must be > 0, got {value}")
    floats = {key: float(_number(path, data, key)) for key in INTRINSICS_FLOAT_KEYS}
    if floats["fx"] <= 0 or floats["fy"] <= 0:
        raise RecordingError(f"{path}: focal lengths must be > 0, got fx={floats['fx']}, fy={floats['fy']}")
    return Intrinsics(**ints, **floats)


def _read_poses(path: Path, frames: int) -> np.ndarray:
    """[frames, 4, 4] f64 poses from poses.txt, checking indices, counts and rigidity line by line."""
    if not path.is_file():
        raise RecordingError(f"{path}: missing")
    poses = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{path} line {lineno}"
        tokens = line.split()
        if len(tokens) != 17:
            raise RecordingError(f"{where}: expected a frame index and 16 numbers, got {len(tokens)} fields")
        try:
            index = int(tokens[0])
            T = np.array([float(t) for t in tokens[1:]], np.float64).reshape(4, 4)
        except ValueError as e:
            raise RecordingError(f"{where}: cannot parse ({e})") from e
        if index != len(poses):
            raise RecordingError(f"{where}: frame index {index}, expected {len(poses)} (frames in order)")
        if not is_rigid(T):
            raise RecordingError(f"{where}: pose of frame {index} is not a rigid transform")
        poses.append(T)
    if len(poses) != frames:
        raise RecordingError(f"{path}: {len(poses)} poses but meta.json says frames = {frames}")
    return np.stack(poses) if poses else np.zeros((0, 4, 4))


def read_recording(folder: str | Path) -> Recording:
    """Read and fully validate a recording folder (see the module docstring for the format).

    Every file is checked before anything is returned; a problem raises :class:`RecordingError` naming the
    file and the key, line or frame. Returns depth [T, H, W] f32 metres and T_wc [T, 4, 4] f64.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such recording folder")
    meta = _read_meta(folder / "meta.json")
    frames, depth_scale = int(meta["frames"]), float(meta["depth_scale"])
    intrinsics = _read_intrinsics(folder / "intrinsics.json")
    T_wc = _read_poses(folder / "poses.txt", frames)

    depth_dir = folder / "depth"
    if not depth_dir.is_dir():
        raise RecordingError(f"{depth_dir}: missing depth folder")
    expected = [f"{i:06d}.png" for i in range(frames)]
    present = {p.name for p in depth_dir.iterdir() if p.suffix.lower() == ".png"}
    missing = [name for name in expected if name not in present]
    if missing:
        raise RecordingError(f"{depth_dir / missing[0]}: missing depth frame {int(missing[0][:6])} "
                             f"({len(missing)} missing of frames = {frames} in meta.json)")
    if len(present) != frames:
        extra = sorted(present - set(expected))
        raise RecordingError(f"{depth_dir}: {len(present)} PNGs but meta.json says frames = {frames} "
                             f"(unexpected: {extra[:5]})")
    depth = np.zeros((frames, intrinsics.height, intrinsics.width), np.float32)
    for i, name in enumerate(expected):
        depth[i] = raw_to_depth(_read_png16(depth_dir / name, intrinsics), depth_scale)
    return Recording(depth=depth, T_wc=T_wc, intrinsics=intrinsics, table_height=float(meta["table_height"]),
                     scene=meta.get("scene"))
