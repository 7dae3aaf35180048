"""Depth renderers against analytic geometry, against each other, and their return/error contract."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxcls.geometry import Intrinsics, look_at, pixel_rays, rotation_to_quat
from jaxcls.world.render import DepthFrames, contract, default_backend, make_renderer, object_ids_of_geoms, testing
from jaxcls.world.render import warp as warp_backend

# float64 C ray casting against float64 analytic intersections: only rounding separates them.
_ANALYTIC_TOL = 1e-4  # m
# mjx casts in float32 (about 1e-7 relative, far below 1 mm at 1 m); a ray grazing a silhouette or a mesh
# edge may fall either side in one backend and not the other, hence fractions rather than all pixels.
_AGREE_TOL = 1e-3  # m
_AGREE_FRACTION = 0.995

INTR = Intrinsics.kinect_v1(0.1)  # 64 x 48, the Kinect's field of view
TABLE_HEIGHT = 0.7


@pytest.fixture(scope="module")
def primitives() -> mujoco.MjModel:
    """Table, yawed box, sphere, a marker geom that rays must ignore; no mesh (analytic depth)."""
    return testing.primitives_scene(INTR, table_height=TABLE_HEIGHT, mesh=False)


@pytest.fixture(scope="module")
def with_mesh() -> mujoco.MjModel:
    """The same plus a 24-sided cylinder mesh ``object_2``."""
    return testing.primitives_scene(INTR, table_height=TABLE_HEIGHT, mesh=True)


@pytest.fixture(scope="module")
def native(with_mesh) -> object:
    return make_renderer(with_mesh, INTR, "mujoco", workers=2)


@pytest.fixture(scope="module")
def mjx_renderer(with_mesh) -> object:
    return make_renderer(with_mesh, INTR, "mjx")


def _oblique_views() -> np.ndarray:
    """[3, 4, 4] views off the scene's symmetry axes (no ray exactly through a mesh vertex)."""
    target = np.array([0.013, -0.007, TABLE_HEIGHT + 0.03])
    eyes = np.array([[0.47, -0.38, 0.55], [-0.31, 0.44, 0.83], [0.09, 0.13, 0.92]])
    eyes[:, 2] += TABLE_HEIGHT
    return look_at(eyes, target)


# ---------------------------------------------------------------- analytic reference

def _ray_box(o: np.ndarray, d: np.ndarray, center: np.ndarray, R: np.ndarray, half: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the first hit of rays o + t d (d: [N, 3]) with an oriented box, inf if none."""
    ol, dl = (o - center) @ R, d @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - ol) / dl, (half - ol) / dl
    t_near = np.max(np.minimum(t1, t2), axis=-1)
    t_far = np.min(np.maximum(t1, t2), axis=-1)
    hit = (t_near <= t_far) & (t_far >= 0)
    return np.where(hit, np.where(t_near >= 0, t_near, t_far), np.inf)


def _ray_sphere(o: np.ndarray, d: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    oc = o - center
    a, b, c = np.sum(d * d, -1), np.sum(d * oc, -1), oc @ oc - radius**2
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0))
    t0, t1 = (-b - root) / a, (-b + root) / a
    t = np.where(t0 >= 0, t0, np.where(t1 >= 0, t1, np.inf))
    return np.where(disc >= 0, t, np.inf)


def _analytic(model: mujoco.MjModel, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[H, W] z-depth and object id of the box/sphere/table scene by closed-form ray intersection."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    dirs = pixel_rays(INTR).reshape(-1, 3) @ T_wc[:3, :3].T  # camera z = 1: ray parameter = z-depth
    o = T_wc[:3, 3]
    ids = object_ids_of_geoms(model)
    rendered = contract.rendered_geoms(model)
    ts, labels = [], []
    for g in np.nonzero(rendered)[0]:
        center, R, size = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3), model.geom_size[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            ts.append(_ray_box(o, dirs, center, R, size))
        elif model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
            ts.append(_ray_sphere(o, dirs, center, size[0]))
        else:
            raise AssertionError("analytic reference knows boxes and spheres only")
        labels.append(ids[g])
    ts = np.stack(ts)
    first = np.argmin(ts, axis=0)
    t = ts[first, np.arange(ts.shape[1])]
    hit = np.isfinite(t)
    depth = np.where(hit, t, 0.0)
    object_id = np.where(hit, np.asarray(labels)[first], -1)
    return depth.reshape(INTR.height, INTR.width), object_id.reshape(INTR.height, INTR.width)


def _box_and_sphere(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom = {int(object_ids_of_geoms(model)[g]): g for g in range(model.ngeom)}
    return data.geom_xpos[geom[0]], data.geom_xpos[geom[1]]


def test_object_ids_of_geoms(with_mesh):
    # geoms: table, box, sphere, cylinder mesh, marker
    np.testing.assert_array_equal(object_ids_of_geoms(with_mesh), [-1, 0, 1, 2, -1])
    assert object_ids_of_geoms(with_mesh).dtype == np.int32


@pytest.mark.parametrize("view", ["down_box", "down_sphere", "down_marker", "oblique", "low_oblique"])
def test_native_matches_analytic(primitives, view):
    box, sphere = _box_and_sphere(primitives)
    T = {
        "down_box": look_at(box + np.array([0, 0, 0.5]), box),
        "down_sphere": look_at(sphere + np.array([0, 0, 0.4]), sphere),
        # the marker sphere hangs 0.5 m above the table here: rays must pass through it
        "down_marker": look_at([0.3, -0.25, TABLE_HEIGHT + 0.9], [0.3, -0.25, TABLE_HEIGHT]),
        "oblique": _oblique_views()[0],
        "low_oblique": look_at([-0.6, -0.35, TABLE_HEIGHT + 0.25], [0.05, 0.02, TABLE_HEIGHT + 0.04]),
    }[view]
    frames = make_renderer(primitives, INTR, "mujoco", workers=1).render(T)
    depth, object_id = frames.depth[0], frames.object_id[0]
    ref_depth, ref_id = _analytic(primitives, T)

    hit, ref_hit = depth > 0, ref_depth > 0
    assert np.mean(hit == ref_hit) >= 0.999, f"{view}: hit masks differ on {np.sum(hit != ref_hit)} px"
    both = hit & ref_hit
    err = np.abs(depth[both] - ref_depth[both])
    assert err.max() < _ANALYTIC_TOL, f"{view}: max depth error {err.max():.2e} m"
    assert np.mean(object_id[both] == ref_id[both]) >= 0.999, f"{view}: object ids differ"
    assert np.all(object_id[~hit] == -1)

    if view == "down_box":  # the box's top face is a plane at constant z-depth
        top = box[2] + primitives.geom_size[1, 2]
        np.testing.assert_allclose(depth[object_id == 0], T[2, 3] - top, atol=_ANALYTIC_TOL)
        assert np.sum(object_id == 0) > 50
    if view == "down_sphere":
        assert np.sum(object_id == 1) > 50
    if view == "down_marker":
        centre = depth[INTR.height // 2 - 4: INTR.height // 2 + 4, INTR.width // 2 - 4: INTR.width // 2 + 4]
        np.testing.assert_allclose(centre, 0.9, atol=_ANALYTIC_TOL)  # the table, not the marker at 0.4


def test_native_threads_match_one_worker(with_mesh):
    T = _oblique_views()
    one = make_renderer(with_mesh, INTR, "mujoco", workers=1).render(T)
    many = make_renderer(with_mesh, INTR, "mujoco", workers=3).render(T)
    np.testing.assert_array_equal(one.depth, many.depth)
    np.testing.assert_array_equal(one.object_id, many.object_id)


def test_native_culling_matches_casting_every_pixel(with_mesh):
    """The default casts only pixels near objects in C and intersects the table box in closed form."""
    T = np.concatenate([_oblique_views(), look_at([0.9, 0.0, TABLE_HEIGHT + 0.05], [0, 0, TABLE_HEIGHT])[None]])
    culled = make_renderer(with_mesh, INTR, "mujoco", workers=1).render(T)
    every = make_renderer(with_mesh, INTR, "mujoco", workers=1, cull=False).render(T)
    np.testing.assert_array_equal(culled.object_id, every.object_id)
    np.testing.assert_allclose(culled.depth, every.depth, atol=1e-6)


def test_mjx_matches_native(native, mjx_renderer):
    T = _oblique_views()
    a = native.render(T)
    b = mjx_renderer.render(T)
    b_depth, b_id = np.asarray(b.depth), np.asarray(b.object_id)
    hit_a, hit_b = a.depth > 0, b_depth > 0
    assert np.mean(hit_a == hit_b) >= _AGREE_FRACTION
    both = hit_a & hit_b
    close = np.abs(a.depth[both] - b_depth[both]) < _AGREE_TOL
    assert np.mean(close) >= _AGREE_FRACTION, f"only {np.mean(close):.4f} of pixels within 1 mm"
    assert np.mean(a.object_id[both] == b_id[both]) >= _AGREE_FRACTION
    for i in (0, 1, 2):  # every object is seen by some view
        assert np.any(a.object_id == i) and np.any(b_id == i)


def test_mjx_chunk_does_not_change_result(with_mesh, mjx_renderer):
    T = _oblique_views()[1]
    odd = make_renderer(with_mesh, INTR, "mjx", chunk=1000).render(T)  # 3072 rays: 3 chunks + remainder
    ref = mjx_renderer.render(T)
    np.testing.assert_array_equal(np.asarray(odd.object_id), np.asarray(ref.object_id))
    # XLA vectorises float32 differently per chunk size: micrometres apart
    np.testing.assert_allclose(np.asarray(odd.depth), np.asarray(ref.depth), atol=1e-5)


def test_mjx_render_is_pure_and_vmaps(with_mesh):
    from jaxcls.world.render import mjx_ray

    mx, dx, geom_object = mjx_ray.put_scene(with_mesh)
    T = jnp.asarray(_oblique_views()[:2], jnp.float32)
    render = jax.jit(lambda T: mjx_ray.render_depth(mx, dx, geom_object, T, INTR, 4096))
    batched = jax.vmap(lambda t: render(t[None]))(T)
    direct = render(T)
    np.testing.assert_array_equal(np.asarray(batched.object_id)[:, 0], np.asarray(direct.object_id))


@pytest.mark.parametrize("backend", ["mujoco", "mjx"])
def test_return_contract(backend, native, mjx_renderer):
    renderer = native if backend == "mujoco" else mjx_renderer
    assert renderer.intrinsics == INTR and renderer.backend == backend
    sky = look_at([0.0, 0.0, TABLE_HEIGHT + 1.0], [0.2, 0.1, TABLE_HEIGHT + 2.0])
    T = np.concatenate([_oblique_views(), sky[None]])
    frames = renderer.render(T)
    assert isinstance(frames, DepthFrames)
    depth, object_id = np.asarray(frames.depth), np.asarray(frames.object_id)
    assert depth.shape == object_id.shape == (4, INTR.height, INTR.width)
    assert frames.depth.dtype == np.float32 and frames.object_id.dtype == np.int32
    assert np.all(np.isfinite(depth)) and np.all(depth >= 0)
    assert np.all(depth[3] == 0) and np.all(object_id[3] == -1), "the sky view must see nothing"
    assert np.all(object_id[depth == 0] == -1), "no return must carry id -1"
    assert np.all(depth[object_id >= 0] > 0)
    assert np.any((object_id == -1) & (depth > 0)), "the table has depth and id -1"

    single = renderer.render(T[0])  # [4, 4] is a batch of one
    np.testing.assert_allclose(np.asarray(single.depth), depth[:1], atol=1e-5)  # mjx: f32 vectorisation
    np.testing.assert_array_equal(np.asarray(single.object_id), object_id[:1])


@pytest.mark.parametrize("backend", ["mujoco", "mjx"])
def test_bad_poses_raise(backend, native, mjx_renderer):
    renderer = native if backend == "mujoco" else mjx_renderer
    T = _oblique_views()[0]
    with pytest.raises(ValueError, match="shape"):
        renderer.render(T[:3])
    with pytest.raises(ValueError, match="shape"):
        renderer.render(np.stack([T, T])[None])
    with pytest.raises(ValueError, match="shape"):
        renderer.render(np.zeros((0, 4, 4)))
    scaled = T.copy()
    scaled[:3, :3] *= 1.1
    with pytest.raises(ValueError, match="not rigid"):
        renderer.render(scaled)
    nan = T.copy()
    nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        renderer.render(np.stack([T, nan]))


def test_bad_backend_and_options(with_mesh):
    with pytest.raises(ValueError, match="unknown render backend"):
        make_renderer(with_mesh, INTR, "opengl")
    with pytest.raises(ValueError, match="workers"):
        make_renderer(with_mesh, INTR, "mujoco", workers=0)
    with pytest.raises(TypeError):
        make_renderer(with_mesh, INTR, "mujoco", chunk=3)


def test_scene_contract_errors():
    spec = testing.scene_spec(INTR)
    with pytest.raises(ValueError, match="object_"):
        make_renderer(spec.compile(), INTR, "mujoco")
    testing.add_object(spec, 0, [0, 0, 0.05], type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0],
                       material="")
    with pytest.raises(ValueError, match="material"):
        make_renderer(spec.compile(), INTR, "mujoco")


@pytest.mark.skipif(default_backend() != "warp", reason="needs a CUDA GPU and warp-lang")
@pytest.mark.parametrize("kinematics", ["forward", "static"])
def test_warp_matches_native(with_mesh, native, kinematics):
    renderer = make_renderer(with_mesh, INTR, "warp", kinematics=kinematics)
    assert renderer.backend == "warp" and renderer.intrinsics == INTR
    T = _oblique_views()
    a, b = native.render(T), renderer.render(T)
    b_depth, b_id = np.asarray(b.depth), np.asarray(b.object_id)
    assert b.depth.dtype == np.float32 and b.object_id.dtype == np.int32
    assert np.all(np.isfinite(b_depth)) and np.all(b_id[b_depth == 0] == -1)
    assert np.mean((a.depth > 0) == (b_depth > 0)) >= _AGREE_FRACTION
    both = (a.depth > 0) & (b_depth > 0)
    assert np.mean(np.abs(a.depth[both] - b_depth[both]) < _AGREE_TOL) >= _AGREE_FRACTION
    assert np.mean(a.object_id[both] == b_id[both]) >= _AGREE_FRACTION
    single = renderer.render(T[1])
    np.testing.assert_allclose(np.asarray(single.depth)[0], b_depth[1], atol=1e-5)


@pytest.mark.skipif(default_backend() == "warp", reason="a GPU and warp-lang are present")
def test_warp_without_gpu_says_how_to_install(with_mesh):
    assert default_backend() == "mujoco"
    with pytest.raises(RuntimeError, match=r"warp.*unavailable.*pip install"):
        make_renderer(with_mesh, INTR, "warp")


_CHOICE = """
import importlib.util, sys
from jaxcls.world.render import factory
factory._has_cuda = lambda: {cuda}
found = importlib.util.find_spec
importlib.util.find_spec = lambda name, *a: (found("json") if {warp} else None) if name == "warp" else found(name, *a)
print(factory.default_backend(), factory.loads_beside_renders("static"), factory.loads_beside_renders("forward"),
      "mujoco.mjx" in sys.modules)
"""


@pytest.mark.parametrize(("cuda", "warp", "chosen"), [(True, True, "warp"), (True, False, "mujoco"),
                                                       (False, True, "mujoco")])
def test_the_backend_is_chosen_without_importing_mjx(cuda, warp, chosen):
    """``auto`` is warp exactly where a CUDA device and warp-lang are present, told without importing MJX or
    MuJoCo Warp (~4 s on a GPU machine, spent where the process first renders instead); so is whether a load may
    run beside a render. In a fresh process, a CUDA device and warp-lang's presence given."""
    code = _CHOICE.format(cuda=cuda, warp=warp)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == [chosen, "True", "False", "False"]


# ---------------------------------------------------------------- warp helpers that run on a CPU

def test_warp_out_of_memory_says_what_to_lower(monkeypatch):
    """Warp's render buffers live outside JAX's memory pool: its "Failed to allocate" becomes a MemoryError
    naming the worlds, the frame size and the pool's fraction as set (or JAX's default), and the way out."""
    error = RuntimeError("Failed to allocate 10066329600 bytes on device 'cuda:0'")
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.82")
    message = warp_backend.out_of_memory_message(4096, INTR, error)
    for part in ("4096 worlds", f"{INTR.width}x{INTR.height}", "10066329600 bytes",
                 "XLA_PYTHON_CLIENT_MEM_FRACTION = 0.82", "lower the fraction"):
        assert part in message, (part, message)
    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION")
    assert "0.75 (JAX's default)" in warp_backend.out_of_memory_message(8, INTR, error)


def _random_rotations(n: int, seed: int = 0) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    R = Rotation.random(n, random_state=seed).as_matrix()
    half_turns = np.array([np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])])
    return np.concatenate([R, half_turns, np.eye(3)[None]])  # w = 0 and w = 1 corner cases


def test_quat_from_matrix_matches_scipy():
    R = _random_rotations(200)
    q = np.asarray(warp_backend.quat_from_matrix(jnp.asarray(R)))
    ref = rotation_to_quat(R)
    sign = np.where(np.sum(q * ref, -1, keepdims=True) < 0, -1.0, 1.0)  # q and -q are one rotation
    np.testing.assert_allclose(q, sign * ref, atol=1e-5)
    assert np.all(q[:, 0] >= 0)


@pytest.mark.parametrize("mount", ["contract", "offset"])
def test_mocap_poses_move_the_mujoco_camera_to_pose(mount):
    """pose -> mocap, then MuJoCo's own kinematics: the camera lands where the OpenCV pose says."""
    spec = testing.scene_spec(INTR)
    testing.add_object(spec, 0, [0, 0, 0.05], type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0])
    if mount == "offset":  # a camera mounted off the body origin still ends up at T_wc
        cam = spec.camera(contract.CAMERA_NAME)
        cam.pos = [0.02, -0.01, 0.03]
        cam.quat = [math.cos(0.2), math.sin(0.2), 0.0, 0.0]
    model = spec.compile()
    cam, mocap = contract.depth_camera(model)
    T_body_cam = warp_backend.camera_in_body(model, cam)
    T_wc = look_at(np.array([[0.5, -0.4, 0.6], [-0.2, 0.3, 0.9], [0.0, 0.0, 1.0]]), np.zeros(3))
    pos, quat = warp_backend.mocap_poses(jnp.asarray(T_wc), T_body_cam)
    data = mujoco.MjData(model)
    for b in range(len(T_wc)):
        data.mocap_pos[mocap], data.mocap_quat[mocap] = np.asarray(pos[b]), np.asarray(quat[b])
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(data.cam_xpos[cam], T_wc[b, :3, 3], atol=1e-5)
        R_mj = data.cam_xmat[cam].reshape(3, 3)
        np.testing.assert_allclose(R_mj, T_wc[b, :3, :3] @ np.diag([1.0, -1, -1]), atol=1e-5)


def _warp_camera_rays(width: int, height: int, fovy_deg: float) -> np.ndarray:
    """[H, W, 3] unit ray directions in the MuJoCo camera frame, transcribed from MuJoCo Warp's
    ``render_util.compute_ray`` (perspective, no sensorsize), pixel row-major from the top."""
    znear = 0.01
    half_h = znear * math.tan(math.radians(fovy_deg) / 2)
    half_w = half_h * width / height
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    x = -half_w + 2 * half_w * u
    y = half_h - 2 * half_h * v
    xx, yy = np.meshgrid(x, y)
    d = np.stack([xx, yy, -np.full_like(xx, znear)], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("scale", [0.1, 0.25, 1.0])
def test_warp_camera_rays_are_our_pixel_rays(scale):
    intr = Intrinsics.kinect_v1(scale)
    ours = pixel_rays(intr) @ np.diag([1.0, -1, -1])  # OpenCV -> MuJoCo camera frame
    ours /= np.linalg.norm(ours, axis=-1, keepdims=True)
    np.testing.assert_allclose(_warp_camera_rays(intr.width, intr.height, intr.fovy_deg), ours, atol=1e-9)
    # its planar depth dist * cos equals our z-depth: cos = -z of the unit MuJoCo ray = 1 / |pixel_ray|
    cos = -_warp_camera_rays(intr.width, intr.height, intr.fovy_deg)[..., 2]
    np.testing.assert_allclose(cos, 1 / np.linalg.norm(pixel_rays(intr), axis=-1), atol=1e-12)


def test_camera_must_match_intrinsics(with_mesh):
    assert contract.check_camera_matches(with_mesh, INTR) == contract.depth_camera(with_mesh)[0]
    with pytest.raises(ValueError, match="fovy"):
        contract.check_camera_matches(with_mesh, Intrinsics.from_fovy(64, 48, 50.0))
    off_centre = Intrinsics(width=64, height=48, fx=52.5, fy=52.5, cx=30.0, cy=23.5)
    with pytest.raises(ValueError, match="centred principal point"):
        contract.check_camera_matches(with_mesh, off_centre)


def test_unpack_frames():
    W, H, B, ngeom = 4, 3, 2, 5
    n = W * H
    geom_object = jnp.array([-1, 0, 1, 2, -1], jnp.int32)  # table, three objects, other
    layout = warp_backend.BufferLayout(depth_adr=7, seg_adr=2, width=W, height=H)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 2.0, (B, n)).astype(np.float32)
    geom = rng.integers(-1, ngeom, (B, n)).astype(np.int32)
    kind = np.where(geom >= 0, int(mujoco.mjtObj.mjOBJ_GEOM), -1).astype(np.int32)
    kind[0, 5] = int(mujoco.mjtObj.mjOBJ_FLEX)  # a flex hit is no object
    depth[geom < 0] = 0.0
    depth[1, 3], geom[1, 3], kind[1, 3] = np.nan, 1, int(mujoco.mjtObj.mjOBJ_GEOM)  # never NaN out
    depth_buf = np.concatenate([np.full((B, 7), 9.0, np.float32), depth, np.full((B, 4), 9.0, np.float32)], 1)
    seg = np.stack([geom, kind], -1)
    seg_buf = np.concatenate([np.full((B, 2, 2), 3, np.int32), seg], 1)

    frames = jax.jit(warp_backend.unpack_frames)(jnp.asarray(depth_buf), jnp.asarray(seg_buf), layout,
                                                 geom_object)
    assert frames.depth.shape == frames.object_id.shape == (B, H, W)
    assert frames.depth.dtype == jnp.float32 and frames.object_id.dtype == jnp.int32
    hit = (geom >= 0) & (kind == int(mujoco.mjtObj.mjOBJ_GEOM))
    valid = hit & np.isfinite(depth) & (depth > 0)
    expect_id = np.where(valid, np.asarray(geom_object)[np.maximum(geom, 0)], -1)  # depth 0 <-> id -1
    expect_depth = np.where(valid, depth, 0.0)
    np.testing.assert_array_equal(np.asarray(frames.object_id), expect_id.reshape(B, H, W))
    np.testing.assert_array_equal(np.asarray(frames.depth), expect_depth.reshape(B, H, W))


def test_posed_geoms_are_mujocos_kinematics():
    """``warp.posed_geoms`` (the static path's geoms carried by their mocap bodies, in JAX) against MuJoCo's own
    kinematics: a mocap body turned at rest with an offset geom, a body fixed under it (no joint) with its own
    offset geom, geoms nothing moves; mocap quaternions not of unit norm (MuJoCo normalises them), one zero."""
    spec = testing.scene_spec(INTR)
    testing.add_object(spec, 0, [0.1, 0.0, 0.05], type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0])
    carrier = spec.worldbody.add_body(name="object_1", mocap=True, pos=[0.2, -0.1, 0.3],
                                      quat=[math.cos(0.4), 0.3, math.sin(0.4), 0.1])
    carrier.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.03, 0.04], pos=[0.05, 0.01, -0.02],
                     quat=[0.9, 0.1, -0.3, 0.2], material="object_mat")
    child = carrier.add_body(name="object_2", pos=[0.0, 0.1, 0.02], quat=[math.cos(0.7), 0.0, 0.0, math.sin(0.7)])
    child.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.01, 0.03, 0], pos=[0.03, 0, 0.01],
                   material="object_mat")
    model = spec.compile()
    rig = warp_backend.geom_rig(model)
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(4, model.nmocap, 3)) * 0.3
    quat = rng.normal(size=(4, model.nmocap, 4)) * 2.0
    quat[1, 0] = 0.0  # a zero quaternion: MuJoCo's identity
    xpos, xmat = warp_backend.posed_geoms(rig, jnp.asarray(pos, jnp.float32), jnp.asarray(quat, jnp.float32))
    data = mujoco.MjData(model)
    for b in range(len(pos)):
        data.mocap_pos[:], data.mocap_quat[:] = pos[b], quat[b]
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(xpos[b], data.geom_xpos, atol=2e-6)
        np.testing.assert_allclose(xmat[b], data.geom_xmat.reshape(-1, 3, 3), atol=2e-6)
    assert np.asarray(rig.mocap).tolist().count(-1) == 2  # the table and the fixed object_0
    jointed = testing.scene_spec(INTR)
    hinged = jointed.worldbody.add_body(name="object_0")
    hinged.add_joint(type=mujoco.mjtJoint.mjJNT_HINGE)
    hinged.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0], material="object_mat")
    with pytest.raises(ValueError, match="1 joints: use kinematics='forward'"):
        warp_backend.geom_rig(jointed.compile())


def test_posed_data_static_writes_the_camera_frame(with_mesh):
    """The static path of the warp backend, on a JAX-impl Data (the fields are the same)."""
    from mujoco import mjx

    cam, _ = contract.depth_camera(with_mesh)
    data = mujoco.MjData(with_mesh)
    mujoco.mj_forward(with_mesh, data)
    dx0 = mjx.make_data(with_mesh, impl="jax")
    T = _oblique_views()
    gx = jnp.asarray(data.geom_xpos, jnp.float32)
    gm = jnp.asarray(data.geom_xmat.reshape(-1, 3, 3), jnp.float32)
    dx = jax.jit(warp_backend.posed_data_static, static_argnames="cam_id")(dx0, jnp.asarray(T), gx, gm,
                                                                            cam_id=cam)
    assert dx.cam_xpos.shape == (3, with_mesh.ncam, 3) and dx.geom_xmat.shape == (3, with_mesh.ngeom, 3, 3)
    np.testing.assert_allclose(dx.cam_xpos[:, cam], T[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(dx.cam_xmat[:, cam], T[:, :3, :3] @ np.diag([1.0, -1, -1]), atol=1e-6)
    np.testing.assert_allclose(dx.geom_xpos[1], data.geom_xpos, atol=1e-6)
    # One geom pose a world (the scene bank's, ``posed_geoms``): each world keeps its own.
    shift = jnp.arange(3.0)[:, None, None] * jnp.array([0.1, -0.2, 0.05])
    quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # a quarter turn about z
    turn = jnp.asarray(np.stack([np.eye(3), quarter, np.eye(3)]), jnp.float32)
    per_world = jax.jit(warp_backend.posed_data_static, static_argnames="cam_id")(
        dx0, jnp.asarray(T), gx[None] + shift, jnp.einsum("bij,gjk->bgik", turn, gm), cam_id=cam)
    np.testing.assert_allclose(per_world.geom_xpos, np.asarray(gx)[None] + np.asarray(shift), atol=1e-6)
    np.testing.assert_allclose(per_world.geom_xmat[1], np.einsum("ij,gjk->gik", np.asarray(turn[1]), gm), atol=1e-6)
    np.testing.assert_allclose(per_world.cam_xpos[:, cam], T[:, :3, 3], atol=1e-6)
