"""TSDF fusion against analytic planes, against itself (scan, vmap), Open3D, the ground-truth meshes, bad
inputs and finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

from jaxcls.geometry import Intrinsics, hemisphere_viewpoints, look_at
from jaxcls.perception import tsdf
from jaxcls.world.setup import WorldConfig, make_world

SMALL = Intrinsics.kinect_v1(0.25)  # 160 x 120, the Kinect's field of view
# f32 arithmetic on values of order 1: only rounding separates the TSDF from the analytic signed distance.
_VALUE_TOL = 1e-5
# Linear interpolation of a zero between voxels of an exactly linear TSDF: rounding only; 0.1 voxel is the brief.
_PLANE_TOL_VOXELS = 0.1
# Open3D's legacy UniformTSDFVolume fuses the same projective TSDF: one voxel is the brief's bound.
_PEER_CHAMFER_VOXELS = 1.0
# Ideal depth, 10 views, 4.7 mm voxels: the brief's bound on the median distance to the true surface.
_GT_MEDIAN_M = 2e-3


def _down_camera(height: float, xy=(0.0, 0.0)) -> np.ndarray:
    """[4, 4] T_wc of a camera at ``height`` m above the point ``xy`` on z = 0, looking straight down."""
    eye = np.array([xy[0], xy[1], height])
    return look_at(eye, eye - np.array([0.0, 0.0, 1.0]))


def _wall(intr: Intrinsics, distance: float) -> np.ndarray:
    """[H, W] f32 depth of a fronto-parallel plane at ``distance`` m."""
    return np.full((intr.height, intr.width), distance, np.float32)


def _voxel_centres(volume: tsdf.TSDFVolume) -> np.ndarray:
    """[X, Y, Z, 3] world voxel centres."""
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in volume.shape], indexing="ij"), axis=-1)
    return np.asarray(volume.origin) + volume.voxel_size * idx


def _surface_points(surface: tsdf.Surface) -> tuple[np.ndarray, np.ndarray]:
    mask = np.asarray(surface.mask)
    return np.asarray(surface.points)[mask], np.asarray(surface.normals)[mask]


def test_create_volume_is_a_cube_of_voxel_centres():
    vol = tsdf.create_volume(np.array([0.1, -0.2, 0.3]), size=0.6, resolution=128)
    assert vol.shape == (128, 128, 128)
    assert vol.tsdf.dtype == jnp.float32 and vol.weight.dtype == jnp.float32 and vol.origin.dtype == jnp.float32
    assert np.all(np.asarray(vol.tsdf) == 1) and np.all(np.asarray(vol.weight) == 0)
    np.testing.assert_allclose(vol.voxel_size, 0.6 / 128)
    # Voxel centres are symmetric about the centre: the first at corner + half a voxel.
    np.testing.assert_allclose(np.asarray(vol.origin), np.array([0.1, -0.2, 0.3]) - 0.3 + 0.3 / 128, atol=1e-6)
    assert 4 * vol.voxel_size <= vol.truncation <= 5 * vol.voxel_size
    with pytest.raises(ValueError, match="center"):
        tsdf.create_volume(np.array([0.0, np.nan, 0.0]))


def test_plane_tsdf_is_signed_distance_and_surface_lies_on_it():
    """Camera 0.5 m above the table looking down: TSDF = height above z = 0 over the truncation."""
    vol = tsdf.create_volume(np.array([0.01, -0.02, 0.003]), size=0.2, resolution=32)
    out = tsdf.integrate(vol, jnp.asarray(_wall(SMALL, 0.5)), SMALL, jnp.asarray(_down_camera(0.5), jnp.float32))
    height = _voxel_centres(vol)[..., 2]
    seen = height >= -vol.truncation  # the rest is behind the band: untouched
    np.testing.assert_allclose(np.asarray(out.weight), seen.astype(np.float32), err_msg="weight")
    expected = np.where(seen, np.clip(height / vol.truncation, -1, 1), 1.0)
    np.testing.assert_allclose(np.asarray(out.tsdf), expected, atol=_VALUE_TOL, err_msg="tsdf")

    surface = tsdf.extract_surface(out, max_points=4096)
    points, normals = _surface_points(surface)
    assert len(points) == 32 * 32  # one crossing per vertical column, none at the band's far edge
    assert np.abs(points[:, 2]).max() <= _PLANE_TOL_VOXELS * vol.voxel_size
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(points), 1)), atol=1e-4, err_msg="normals")
    assert not np.any(np.asarray(surface.points)[~np.asarray(surface.mask)])  # padding is zero


def test_oblique_wall_surface_and_normals_face_the_camera():
    """A wall seen off-axis: zero crossings on the plane, normals towards the camera."""
    intr = Intrinsics.kinect_v1(0.5)
    T_wc = look_at(np.array([0.3, -0.2, 0.6]), np.zeros(3))
    distance = float(np.linalg.norm([0.3, -0.2, 0.6]))
    vol = tsdf.create_volume(np.zeros(3), size=0.2, resolution=40)
    out = tsdf.integrate(vol, jnp.asarray(_wall(intr, distance)), intr, jnp.asarray(T_wc, jnp.float32))
    points, normals = _surface_points(tsdf.extract_surface(out, max_points=20000))
    assert len(points) > 1000
    axis = T_wc[:3, 2]  # the plane is z_cam = distance: normal -axis
    offset = (points - T_wc[:3, 3]) @ axis - distance
    assert np.abs(offset).max() <= _PLANE_TOL_VOXELS * vol.voxel_size
    assert np.min(normals @ -axis) > 0.99


def test_scan_equals_one_by_one_and_vmap_over_volumes():
    rng = np.random.default_rng(0)
    views = hemisphere_viewpoints(np.zeros(3), count=8)[::3]  # 3 views
    depths = np.stack([rng.uniform(0.9, 1.1, (SMALL.height, SMALL.width)) for _ in views]).astype(np.float32)
    depths[0, :10] = 0.0
    vol = tsdf.create_volume(np.zeros(3), size=0.3, resolution=24)
    scanned = tsdf.integrate_frames(vol, jnp.asarray(depths), SMALL, jnp.asarray(views, jnp.float32))
    single = vol
    for d, T in zip(depths, views, strict=True):
        single = tsdf.integrate(single, jnp.asarray(d), SMALL, jnp.asarray(T, jnp.float32))
    assert np.asarray(single.weight).max() == 3
    # 1e-5: XLA may contract the scan body's multiply-adds differently (~1 float32 ulp of z / truncation).
    np.testing.assert_allclose(np.asarray(scanned.tsdf), np.asarray(single.tsdf), atol=1e-5, err_msg="tsdf")
    np.testing.assert_array_equal(np.asarray(scanned.weight), np.asarray(single.weight), err_msg="weight")

    # A batch of episodes: one volume per view, vmapped, equals each integrated alone.
    batch = jax.tree.map(lambda x: jnp.stack([x] * len(views)), vol)
    fused = jax.vmap(lambda v, d, T: tsdf.integrate(v, d, SMALL, T))(
        batch, jnp.asarray(depths), jnp.asarray(views, jnp.float32))
    for b in range(len(views)):
        alone = tsdf.integrate(vol, jnp.asarray(depths[b]), SMALL, jnp.asarray(views[b], jnp.float32))
        np.testing.assert_allclose(np.asarray(fused.tsdf[b]), np.asarray(alone.tsdf), atol=1e-6)


@pytest.fixture(scope="module")
def scene_frames():
    """A builtin 5-object scene and its depth at 10 hemisphere views, 640x480 (ideal sensor)."""
    world = make_world(WorldConfig(backend="mujoco"), seed=0)
    views = world.viewpoints[::10]
    frames = world.render(np.arange(0, 100, 10))
    return world.scene, world.models, world.centroid, world.intrinsics, views, np.asarray(frames.depth)


@pytest.fixture(scope="module")
def fused_scene(scene_frames):
    _, _, centre, intr, views, depths = scene_frames
    vol = tsdf.integrate_frames(tsdf.create_volume(centre), jnp.asarray(depths), intr,
                                jnp.asarray(views, jnp.float32))
    return vol, tsdf.extract_surface(vol, max_points=100_000)


def test_same_surface_as_open3d(scene_frames, fused_scene):
    o3d = pytest.importorskip("open3d")
    integration = o3d.pipelines.integration
    _, _, centre, intr, views, depths = scene_frames
    vol, surface = fused_scene
    # Open3D's origin is the cube's corner; its voxel centres sit half a voxel inside (found empirically:
    # with the corner the surfaces agree to ~0.01 voxel, with the centre convention they are ~0.8 apart).
    peer = integration.UniformTSDFVolume(0.6, 128, vol.truncation, integration.TSDFVolumeColorType.NoColor,
                                         np.asarray(centre, float) - 0.3)
    K = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
    for depth, T_wc in zip(depths, views, strict=True):
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.zeros((*depth.shape, 3), np.uint8)), o3d.geometry.Image(depth.astype(np.float32)),
            depth_scale=1.0, depth_trunc=100.0, convert_rgb_to_intensity=False)
        peer.integrate(rgbd, K, np.linalg.inv(T_wc))
    theirs = np.asarray(peer.extract_point_cloud().points)
    ours, _ = _surface_points(surface)
    assert len(ours) < 100_000, "raise max_points: the surface was subsampled"
    assert 0.8 < len(ours) / len(theirs) < 1.25, (len(ours), len(theirs))
    chamfer = 0.5 * (cKDTree(theirs).query(ours)[0].mean() + cKDTree(ours).query(theirs)[0].mean())
    assert chamfer <= _PEER_CHAMFER_VOXELS * vol.voxel_size, f"chamfer {chamfer / vol.voxel_size:.3f} voxels"


def test_surface_matches_the_object_meshes(scene_frames, fused_scene):
    o3d = pytest.importorskip("open3d")
    scene, models, _, _, _, _ = scene_frames
    _, surface = fused_scene
    points, normals = _surface_points(surface)
    assert np.all(np.isfinite(points)) and np.all(np.isfinite(normals))
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5, err_msg="unit normals")
    on_objects = points[:, 2] > scene.table_height + 0.005
    assert on_objects.sum() > 2000
    # Exact point-to-triangle distance to the union of the posed meshes (Open3D's raycasting scene).
    raycast = o3d.t.geometry.RaycastingScene()
    for model, pose in zip(models, scene.object_poses(), strict=True):
        mesh = model.mesh.copy().apply_transform(pose)
        raycast.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                              o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    distance = raycast.compute_distance(o3d.core.Tensor(points[on_objects].astype(np.float32))).numpy()
    assert np.median(distance) <= _GT_MEDIAN_M, f"median {np.median(distance) * 1e3:.2f} mm"
    # The table's points lie on the table plane (within ~0.2 voxel: nearest-pixel depth at oblique views).
    table = points[np.abs(points[:, 2] - scene.table_height) < 0.005]
    assert np.median(np.abs(table[:, 2] - scene.table_height)) < 1e-3


def test_empty_and_subsampled_extraction():
    vol = tsdf.create_volume(np.zeros(3), size=0.2, resolution=32)
    empty = tsdf.extract_surface(vol, max_points=64)
    assert not np.any(np.asarray(empty.mask)) and np.all(np.asarray(empty.points) == 0)
    out = tsdf.integrate(vol, jnp.asarray(_wall(SMALL, 0.5)), SMALL, jnp.asarray(_down_camera(0.5), jnp.float32))
    full, _ = _surface_points(tsdf.extract_surface(out, max_points=4096))
    sub = tsdf.extract_surface(out, max_points=100)
    points, _ = _surface_points(sub)
    assert len(points) == 100 and len(np.unique(points, axis=0)) == 100
    assert cKDTree(full).query(points)[0].max() < 1e-6  # a subset of the full surface
    assert np.ptp(points[:, 0]) > 0.8 * np.ptp(full[:, 0])  # spread over it, not its first rows


@pytest.mark.parametrize("shape", [(20, 23, 37), (16, 16, 64)])
def test_extraction_finds_every_crossing_edge(shape):
    """Every edge between trusted voxels of opposite sign, enumerated in NumPy, and nothing else (any grid
    size: z rows that are not a multiple of the 32-bit words included), in axis-major voxel order."""
    rng = np.random.default_rng(3)
    f = np.clip(rng.normal(0.0, 0.8, shape), -1.0, 1.0).astype(np.float32)
    w = (rng.random(shape) > 0.2).astype(np.float32)
    vol = tsdf.create_volume(np.zeros(3), 0.2, 8).replace(tsdf=jnp.asarray(f), weight=jnp.asarray(w))
    ok = (w >= 1) & (np.abs(f) < 0.99)
    expected = []
    for a in range(3):
        lo, hi = [slice(None)] * 3, [slice(None)] * 3
        lo[a], hi[a] = slice(0, -1), slice(1, None)
        lo, hi = tuple(lo), tuple(hi)
        edge = ok[lo] & ok[hi] & ((f[lo] >= 0) != (f[hi] >= 0))
        idx = np.argwhere(edge)
        f0, f1 = f[lo][edge], f[hi][edge]
        expected.append(idx + np.eye(3)[a] * (f0 / (f0 - f1))[:, None])
    expected = np.asarray(vol.origin) + vol.voxel_size * np.concatenate(expected)
    points, _ = _surface_points(tsdf.extract_surface(vol, max_points=len(expected) + 50))
    np.testing.assert_allclose(points, expected, atol=1e-6)


def test_the_two_ways_to_find_each_slots_word_agree_with_numpy():
    """``_select_bits``' word of each slot: the CPU's binary search and the GPU's one pass over the words (a write
    per run of equal values, then a running max) give NumPy's ``searchsorted(..., side="right")``, with runs of
    empty words, slots no word reaches, values past the slots and a first word already past slot 0."""
    rng = np.random.default_rng(5)
    for size, M in [(64, 1000), (512, 300), (16, 16)]:
        steps = rng.choice([0, 0, 0, 1, 2, 5], M)  # (many empty words: runs of equal values)
        for first_past in (np.minimum(np.cumsum(steps), size), np.minimum(np.cumsum(steps) + 3, size + 7)):
            first_past = first_past.astype(np.int32)
            expected = np.searchsorted(first_past, np.arange(size), side="right")
            for way in (tsdf._word_of_slot_search, tsdf._word_of_slot_scatter):
                np.testing.assert_array_equal(np.asarray(way(jnp.asarray(first_past), size)), expected)


def test_bad_depth_is_ignored():
    vol = tsdf.create_volume(np.zeros(3), size=0.2, resolution=32)
    T = jnp.asarray(_down_camera(0.5), jnp.float32)
    same = tsdf.integrate(vol, jnp.zeros((SMALL.height, SMALL.width)), SMALL, T)
    np.testing.assert_array_equal(np.asarray(same.tsdf), np.asarray(vol.tsdf))
    np.testing.assert_array_equal(np.asarray(same.weight), np.asarray(vol.weight))

    depth = _wall(SMALL, 0.5)
    bad = depth.copy()
    bad[:, :40] = np.nan
    bad[:20] = np.inf
    bad[-20:] = -np.inf
    bad[50:60, 50:60] = -0.5
    clean = np.where(np.isfinite(bad) & (bad > 0), bad, 0.0).astype(np.float32)
    got = tsdf.integrate(vol, jnp.asarray(bad), SMALL, T)
    want = tsdf.integrate(vol, jnp.asarray(clean), SMALL, T)
    assert np.all(np.isfinite(np.asarray(got.tsdf))) and np.all(np.isfinite(np.asarray(got.weight)))
    np.testing.assert_array_equal(np.asarray(got.tsdf), np.asarray(want.tsdf))
    np.testing.assert_array_equal(np.asarray(got.weight), np.asarray(want.weight))
    assert np.asarray(got.weight).sum() < np.asarray(tsdf.integrate(vol, jnp.asarray(depth), SMALL, T).weight).sum()
    # Returns beyond max_depth count as no return.
    far = tsdf.integrate(vol, jnp.asarray(depth), SMALL, T, max_depth=0.4)
    np.testing.assert_array_equal(np.asarray(far.weight), np.asarray(vol.weight))


def test_check_frame_names_the_problem():
    depth = _wall(SMALL, 0.5)
    T = _down_camera(0.5)
    tsdf.check_frame(depth, SMALL, T)  # fine
    with pytest.raises(ValueError, match=r"depth has shape \(160, 120\)"):
        tsdf.check_frame(depth.T, SMALL, T)
    with pytest.raises(ValueError, match="shape"):
        tsdf.check_frame(depth[None], SMALL, T)
    with pytest.raises(ValueError, match="not rigid"):
        tsdf.check_frame(depth, SMALL, T @ np.diag([1.0, 1.0, 1.1, 1.0]))
    with pytest.raises(ValueError, match="not rigid"):
        tsdf.check_frame(depth, SMALL, np.where(np.eye(4) > 0, np.nan, T))
    with pytest.raises(ValueError, match=r"\[4, 4\]"):
        tsdf.check_frame(depth, SMALL, T[:3])


def test_gradient_wrt_depth_matches_finite_differences():
    """Camera 0.3 m above a bumpy table; every voxel is >= 2 mm away from the band's kinks, where the
    TSDF is linear in depth, so central differences are exact up to f32 rounding."""
    intr = Intrinsics.kinect_v1(0.1)  # 64 x 48
    vol = tsdf.create_volume(np.zeros(3), size=0.1, resolution=16)  # centres at +-3.125 mm, +-9.375 mm, ...
    rng = np.random.default_rng(1)
    bumps = rng.uniform(-1e-3, 1e-3, (intr.height, intr.width))
    depth = (0.3 - bumps).astype(np.float32)
    depth[0, 0] = np.nan  # a bad pixel must not poison the gradient
    T = jnp.asarray(_down_camera(0.3), jnp.float32)
    coeff = jnp.asarray(rng.normal(size=vol.shape), jnp.float32)

    def loss(d: jax.Array) -> jax.Array:
        out = tsdf.integrate(vol, d, intr, T)
        out = tsdf.integrate(out, d + vol.voxel_size, intr, T)  # kinks stay midway between voxels
        return jnp.sum(coeff * out.tsdf)

    grad = np.asarray(jax.grad(loss)(jnp.asarray(depth)))
    assert np.all(np.isfinite(grad))
    assert grad[0, 0] == 0
    pixels = np.argwhere(np.abs(grad) > 1e-3)
    assert len(pixels) > 10
    eps = 5e-4
    for v, u in pixels[rng.choice(len(pixels), 8, replace=False)]:
        hi, lo = depth.copy(), depth.copy()
        hi[v, u] += eps
        lo[v, u] -= eps
        fd = (float(loss(jnp.asarray(hi))) - float(loss(jnp.asarray(lo)))) / (2 * eps)
        np.testing.assert_allclose(grad[v, u], fd, rtol=2e-2, atol=1e-2, err_msg=f"pixel {(v, u)}")


def test_compact_storage_fuses_the_same_volume_and_surface(scene_frames, fused_scene):
    """``VolumeStorage.compact`` (int16 fixed-point values, uint8 weights: 3 bytes a voxel, not 8) against the
    float32 reference on the same 10 frames: the same weights, values within the rounding, the same surface."""
    _, _, centre, intr, views, depths = scene_frames
    reference, reference_surface = fused_scene
    compact = tsdf.integrate_frames(tsdf.create_volume(centre, storage="compact"), jnp.asarray(depths), intr,
                                    jnp.asarray(views, jnp.float32))
    assert compact.tsdf.dtype == jnp.int16 and compact.weight.dtype == jnp.uint8
    assert compact.storage is tsdf.VolumeStorage.compact and reference.storage is tsdf.VolumeStorage.float32
    np.testing.assert_array_equal(np.asarray(compact.weight), np.asarray(reference.weight))
    # Half a step of 1 / 32767 a rounding, over <= 10 updates.
    np.testing.assert_allclose(np.asarray(compact.values), np.asarray(reference.values), atol=2e-4)
    ours, _ = _surface_points(tsdf.extract_surface(compact, max_points=100_000))
    theirs, _ = _surface_points(reference_surface)
    assert abs(len(ours) - len(theirs)) <= 0.001 * len(theirs), (len(ours), len(theirs))
    distance = cKDTree(theirs).query(ours)[0]
    assert np.quantile(distance, 0.99) <= 0.01 * reference.voxel_size, np.quantile(distance, 0.99)


def test_compact_weights_saturate_and_keep_averaging():
    """A compact voxel observed more than 255 times keeps weight 255 (KinectFusion's cap) and from then on a
    running average with that weight; the float32 reference counts on and averages every frame alike."""
    first, then = 260, 40  # frames of a wall at 0.95 m, then at 1.0 m, from a camera looking straight down
    T = jnp.asarray(np.stack([_down_camera(1.0)] * (first + then)), jnp.float32)
    walls = jnp.asarray(np.stack([_wall(SMALL, 0.95)] * first + [_wall(SMALL, 1.0)] * then))
    out, alone = {}, {}
    for storage in tsdf.VolumeStorage:
        vol = tsdf.create_volume(np.array([0.0, 0.0, 0.05]), size=0.2, resolution=16, storage=storage)
        out[storage] = tsdf.integrate_frames(vol, walls, SMALL, T)
        alone[storage] = [tsdf.integrate(vol, walls[n], SMALL, T[n]) for n in (0, -1)]
    a, b = (np.asarray(v.values) for v in alone["float32"])  # each wall's own observation
    both = (np.asarray(alone["float32"][0].weight) > 0) & (np.asarray(alone["float32"][1].weight) > 0)
    assert both.sum() > 100
    assert np.asarray(out["float32"].weight)[both].min() == first + then
    np.testing.assert_array_equal(np.asarray(out["compact"].weight)[both], tsdf.MAX_COMPACT_WEIGHT)
    np.testing.assert_allclose(np.asarray(out["float32"].values)[both], ((first * a + then * b) / (first + then))[both],
                               atol=1e-5)
    capped = b + (a - b) * (1.0 - 1.0 / tsdf.MAX_COMPACT_WEIGHT) ** then  # a until frame 260, then weight 255
    np.testing.assert_allclose(np.asarray(out["compact"].values)[both], capped[both], atol=2e-3)


def _plain_slabs(values, start, size, arrays, *operands):
    """``tsdf.slabs_in_place``'s reference: JAX's own slice and update of each array."""
    slabs = [jax.lax.dynamic_slice_in_dim(a, start, size, 0) for a in arrays]
    new = values(start, *slabs, *operands)
    return tuple(jax.lax.dynamic_update_slice_in_dim(a, b, start, 0) for a, b in zip(arrays, new, strict=True))


def test_slabs_in_place_equals_slice_and_update_under_vmap_loops_and_grad():
    """The fusion's slabs batched as slices of the batch (not JAX's scatter): the same values as JAX's slice and
    update, unbatched, vmapped with the slab's start shared or per element, in a loop over slabs, and the same
    derivatives; the batched program holds no scatter (XLA made it a slab copied twice: BENCHMARKS.md)."""
    def values(start, a, b, scale):  # depends on the slab's position, both arrays and a traced operand
        row = (start + jnp.arange(a.shape[0], dtype=jnp.int32)).astype(jnp.float32)[:, None]
        return a * scale + row, (b + a * scale).astype(b.dtype)

    def looped(form, a, b, scale):
        return jax.lax.fori_loop(0, 4, lambda n, c: form(values, n * 2, 2, c, scale), (a, b))

    rng = np.random.default_rng(0)
    a = jnp.asarray(rng.normal(size=(3, 8, 5)), jnp.float32)
    b = jnp.asarray(rng.integers(0, 50, (3, 8, 5)), jnp.int16)
    scale = jnp.asarray([0.5, 2.0, -1.0], jnp.float32)

    def same(x, y):
        for u, v in zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v), strict=True)

    def sliced_in_place(f, *args):  # the batched program slices and updates: no gather, no scatter
        text = jax.jit(f).lower(*args).as_text()
        assert "scatter" not in text and "gather" not in text

    same(looped(tsdf.slabs_in_place, a[0], b[0], scale[0]), looped(_plain_slabs, a[0], b[0], scale[0]))
    ours = jax.vmap(lambda a, b, s: looped(tsdf.slabs_in_place, a, b, s))
    same(jax.jit(ours)(a, b, scale), jax.vmap(lambda a, b, s: looped(_plain_slabs, a, b, s))(a, b, scale))
    sliced_in_place(ours, a, b, scale)
    # An operand shared by the batch, and an array shared by it (broadcast to the batch).
    shared = jax.vmap(lambda a: looped(tsdf.slabs_in_place, a, b[0], scale[1]))
    same(shared(a), jax.vmap(lambda a: looped(_plain_slabs, a, b[0], scale[1]))(a))
    sliced_in_place(shared, a)
    same(jax.vmap(lambda s: tsdf.slabs_in_place(values, 2, 2, (a[0], b[0]), s))(scale),
         jax.vmap(lambda s: _plain_slabs(values, 2, 2, (a[0], b[0]), s))(scale))
    # Each element its own slab: the general form.
    starts = jnp.asarray([0, 2, 6], jnp.int32)
    same(jax.vmap(lambda n, a, b, s: tsdf.slabs_in_place(values, n, 2, (a, b), s))(starts, a, b, scale),
         jax.vmap(lambda n, a, b, s: _plain_slabs(values, n, 2, (a, b), s))(starts, a, b, scale))
    # Derivatives: reverse mode (batched too) and forward mode, those of the slice and update.
    def loss(form):
        return lambda a, s: jnp.sum(looped(form, a, b[0], s)[0] ** 2)
    same(jax.grad(loss(tsdf.slabs_in_place), argnums=(0, 1))(a[0], scale[0]),
         jax.grad(loss(_plain_slabs), argnums=(0, 1))(a[0], scale[0]))
    same(jax.vmap(jax.grad(loss(tsdf.slabs_in_place), argnums=1))(a, scale),
         jax.vmap(jax.grad(loss(_plain_slabs), argnums=1))(a, scale))
    def batch_loss(form):
        return lambda s: jnp.sum(jax.vmap(loss(form))(a, s))

    same(jax.grad(batch_loss(tsdf.slabs_in_place))(scale), jax.grad(batch_loss(_plain_slabs))(scale))
    same(jax.jvp(lambda s: loss(tsdf.slabs_in_place)(a[0], s), (scale[0],), (1.0,)),
         jax.jvp(lambda s: loss(_plain_slabs)(a[0], s), (scale[0],), (1.0,)))


@pytest.mark.parametrize("storage", list(tsdf.VolumeStorage), ids=lambda s: s.value)  # (its encode is not str.encode)
def test_fusion_in_slabs_batched_equals_one_pass(scene_frames, storage):
    """The fusion in slabs (``slabs_in_place`` under vmap: each slab sliced from the batch and written back) fuses
    a batch of volumes as one pass over each does, with no scatter in the batched program: the weights equal, the
    values within float32 rounding (XLA fuses the two forms' arithmetic differently)."""
    _, _, centre, intr, views, depths = scene_frames
    volume = tsdf.create_volume(centre, resolution=64)
    if storage is tsdf.VolumeStorage.compact:
        volume = volume.replace(tsdf=storage.encode(volume.tsdf), weight=volume.weight.astype(jnp.uint8))
    views, depths = jnp.asarray(views[:3], jnp.float32), jnp.asarray(depths[:3])

    def batch(slabs):
        return jax.vmap(lambda d, T: tsdf._integrate(volume, d, intr, T, None, slabs=slabs))

    in_slabs, one_pass = jax.jit(batch(8))(depths, views), jax.jit(batch(1))(depths, views)
    assert "scatter" not in jax.jit(batch(8)).lower(depths, views).as_text()
    np.testing.assert_array_equal(np.asarray(in_slabs.weight), np.asarray(one_pass.weight))
    assert np.asarray(one_pass.weight).max() == 1
    tolerance = 1e-5 if storage is tsdf.VolumeStorage.float32 else 1.5 / tsdf.COMPACT_SCALE  # (< 2 steps)
    np.testing.assert_allclose(np.asarray(in_slabs.values), np.asarray(one_pass.values), rtol=0, atol=tolerance)


@pytest.mark.parametrize("storage", list(tsdf.VolumeStorage), ids=lambda s: s.value)  # (its encode is not str.encode)
def test_pallas_fusion_equals_the_vectorised_fusion(scene_frames, storage):
    """The Pallas fusion (one kernel over blocks of 2,048 voxels, in place; here ``FusionKernel.interpreted``) fuses
    the same volumes as the vectorised reference, as an episode holds them: a batch of volumes of their own (vmapped:
    the batch a grid axis), each fusing three views in turn under ``lax.scan`` (each view reads what the last wrote
    in place). The weights are equal; the values within float32 rounding (a compact volume: one step of its fixed
    point). A 48^3 volume (planes of 2,304 voxels: not a power of two) runs the kernel; a 30^3 one (no power-of-two
    factor of 128) the vectorised fusion. ``FusionKernel.pallas`` off a GPU is the vectorised fusion, bit for bit."""
    _, _, centre, intr, views, depths = scene_frames
    views, depths = jnp.asarray(views[:6], jnp.float32), jnp.asarray(depths[:6])

    def empty(resolution):
        volume = tsdf.create_volume(centre, resolution=resolution)
        if storage is tsdf.VolumeStorage.compact:
            volume = volume.replace(tsdf=storage.encode(volume.tsdf), weight=volume.weight.astype(jnp.uint8))
        return jax.tree.map(lambda a: jnp.stack([a, a]), volume)  # two episodes' volumes

    def episodes(kernel, volumes, blocks=tsdf.FUSION_BLOCKS):  # two episodes, three views each: views 0-2, 3-5
        def one(volume, d, T):
            return jax.lax.scan(lambda v, f: (tsdf.integrate(v, f[0], intr, f[1], kernel=kernel, blocks=blocks),
                                              None), volume, (d, T))[0]
        return jax.jit(jax.vmap(one))(volumes, depths.reshape(2, 3, *depths.shape[1:]), views.reshape(2, 3, 4, 4))

    tolerance = 1e-5 if storage is tsdf.VolumeStorage.float32 else 1.5 / tsdf.COMPACT_SCALE  # (< 2 steps)
    for resolution in (64, 48):
        volumes = empty(resolution)
        ours, reference = (episodes(k, volumes) for k in (tsdf.FusionKernel.interpreted, tsdf.FusionKernel.xla))
        np.testing.assert_array_equal(np.asarray(ours.weight), np.asarray(reference.weight))
        assert np.asarray(reference.weight).max() == 3  # (every view sees the scene)
        np.testing.assert_allclose(np.asarray(ours.values), np.asarray(reference.values), rtol=0, atol=tolerance)
        if jax.default_backend() == "cpu":  # (on a GPU, `pallas` is the Triton kernel)
            fallback = episodes(tsdf.FusionKernel.pallas, volumes)
            for a, b in zip(jax.tree.leaves(fallback), jax.tree.leaves(reference), strict=True):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        for kernel in (tsdf.FusionKernel.interpreted, tsdf.FusionKernel.pallas):
            assert "pallas_call" in str(jax.make_jaxpr(lambda v, k=kernel: episodes(k, v))(volumes))
    # Other blocks (8,192 voxels: 4,096 of a 48^3 volume's, the largest power of two dividing it; in one step and
    # in four): the same volumes; blocks that are not powers of two refused by name.
    for blocks in (tsdf.FusionBlocks(8192, 8), tsdf.FusionBlocks(8192, 8, steps=4)):
        other = episodes(tsdf.FusionKernel.interpreted, volumes, blocks)
        np.testing.assert_array_equal(np.asarray(other.weight), np.asarray(ours.weight))
        np.testing.assert_allclose(np.asarray(other.values), np.asarray(ours.values), rtol=0, atol=tolerance)
    with pytest.raises(ValueError, match="blocks"):
        episodes(tsdf.FusionKernel.interpreted, volumes, tsdf.FusionBlocks(1000, 4))
    assert "pallas_call" not in str(jax.make_jaxpr(lambda v: episodes(tsdf.FusionKernel.pallas, v))(empty(30)))


def test_pallas_kernels_lower_for_a_gpu(scene_frames):
    """Both Pallas kernels lower for a CUDA GPU (Triton) from this CPU, batched as an episode batches them: the
    fusion of a compact volume and PointNet's pooled product, each with its default blocks and another, each a
    Triton call in the lowered program (not Mosaic GPU, which cannot batch them). The batch sizes whose uint8
    weights the kernel's 32-bit offsets cannot address are refused (``check_kernel_batch``)."""
    from jaxcls.perception import pointnet

    _, _, centre, intr, views, depths = scene_frames
    storage = tsdf.VolumeStorage.compact
    volume = tsdf.create_volume(centre)
    volume = volume.replace(tsdf=storage.encode(volume.tsdf), weight=volume.weight.astype(jnp.uint8))
    volumes = jax.tree.map(lambda a: jnp.stack([a, a]), volume)

    def fuse(blocks):
        return jax.vmap(lambda v, d, T: tsdf.integrate(v, d, intr, T, kernel=tsdf.FusionKernel.pallas, blocks=blocks))

    def pool(blocks):
        return jax.vmap(lambda x, m, w: pointnet._max_product_in_kernel(x, m, w, blocks=blocks), in_axes=(0, 0, None))

    x = jnp.zeros((2, 1, 256, 128), jnp.bfloat16)
    frames = (volumes, jnp.asarray(depths[:2]), jnp.asarray(views[:2], jnp.float32))
    segments = (x, jnp.ones((2, 1, 256), bool), jnp.zeros((128, 1024)))
    for f, args in ((fuse(tsdf.FUSION_BLOCKS), frames), (fuse(tsdf.FusionBlocks(8192, 8, 4)), frames),
                    (pool(pointnet.POOL_BLOCKS), segments), (pool(pointnet.PoolBlocks(256, 32, 8, True, 4)), segments)):
        try:
            text = jax.jit(f).trace(*args).lower(lowering_platforms=("cuda",)).as_text()
        except (RuntimeError, NotImplementedError) as e:  # (a jaxlib that cannot lower for CUDA without a GPU)
            if "cuda" in str(e).lower() and "unknown" in str(e).lower():
                pytest.skip(f"this jaxlib cannot lower for CUDA here: {e}")
            raise
        assert "__gpu$xla.gpu.triton" in text and "mosaic" not in text.lower()
    for volumes_a_device in (1025, 2048):
        with pytest.raises(ValueError, match="32-bit offsets"):
            tsdf.check_kernel_batch(tsdf.FusionKernel.pallas, storage, 128, volumes_a_device, "gpu")
        tsdf.check_kernel_batch(tsdf.FusionKernel.pallas, storage, 128, volumes_a_device, "cpu")  # (no Triton)
    for kernel, kept, count in ((tsdf.FusionKernel.pallas, storage, 1024), (tsdf.FusionKernel.pallas, storage, 4096),
                                (tsdf.FusionKernel.pallas, tsdf.VolumeStorage.float32, 2048),
                                (tsdf.FusionKernel.xla, storage, 2048)):
        tsdf.check_kernel_batch(kernel, kept, 128, count, "gpu")


def test_round_half_even_is_jnp_round():
    """The Pallas fusion's rounding (floor and compares: Triton has no rounding op) gives ``jnp.round``'s values
    (a zero's sign aside, which neither a pixel index nor a stored value keeps): ties to even both signs, values
    near the ties, large and tiny magnitudes, integers, signed zeros."""
    rng = np.random.default_rng(0)
    ties = np.arange(-70.5, 71.0, 1.0)
    near = np.concatenate([np.nextafter(ties, np.inf), np.nextafter(ties, -np.inf)])
    x = np.concatenate([ties, near, rng.normal(scale=500.0, size=20_000), rng.uniform(-1, 1, 20_000) * 32767.0,
                        [0.0, -0.0, 0.49999997, -0.49999997, 2.0 ** 23 + 1, -(2.0 ** 23) - 1, 2.0 ** 24, 3e9, -3e9,
                         1e-30, 8388607.5, -8388607.5]]).astype(np.float32)
    ours, reference = jax.jit(tsdf.round_half_even)(x), jnp.round(x)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(reference), strict=True)  # (-0.0 == 0.0)
