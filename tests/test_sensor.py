"""The Kinect-v1 sensor model: statistics against its formulas, dropout where it belongs, the contract."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls.geometry import Intrinsics, is_rigid, look_at
from jaxcls.world.render import SensorConfig, apply_sensor, perturb_poses

INTR = Intrinsics.kinect_v1(0.1)  # 64 x 48
KEY = jax.random.PRNGKey(0)
# A sample std of n ~ 20k draws is within ~1% of the truth; the rest is the model's own approximations
# (quantisation as uniform noise of variance step^2 / 12), hence the 15% the brief allows.
_STD_RTOL = 0.15


def _plane(z: float, batch: int = 8) -> jnp.ndarray:
    """[B, H, W] depth of a fronto-parallel plane at z-depth ``z`` (m)."""
    return jnp.full((batch, INTR.height, INTR.width), z, jnp.float32)


def _step_scene() -> np.ndarray:
    """[1, H, W]: a 1.0 m plane with a 0.8 m box in the middle and a hole (no return) on the right."""
    depth = np.full((1, INTR.height, INTR.width), 1.0, np.float32)
    depth[0, 14:34, 16:40] = 0.8
    depth[0, 10:38, 52:58] = 0.0
    return depth


def test_ideal_sensor_is_identity():
    depth = jnp.asarray(_step_scene())
    out = apply_sensor(KEY, depth, INTR, SensorConfig.ideal())
    np.testing.assert_array_equal(np.asarray(out), np.asarray(depth))
    T = jnp.asarray(look_at(np.array([[0.5, 0.2, 0.8]]), np.zeros(3)), jnp.float32)
    np.testing.assert_array_equal(np.asarray(perturb_poses(KEY, T, SensorConfig.ideal())), np.asarray(T))
    np.testing.assert_array_equal(np.asarray(perturb_poses(KEY, T, SensorConfig())), np.asarray(T))


@pytest.mark.parametrize("z", [1.0, 2.0])
def test_plane_noise_matches_model(z):
    config = SensorConfig()
    out = np.asarray(apply_sensor(KEY, _plane(z), INTR, config))[:, 4:-4, 4:-4]
    assert np.all(out > 0), "a fronto-parallel plane in range keeps every interior pixel"
    sigma, step = config.sigma_z(z), config.depth_step(z)
    expected = math.sqrt(sigma**2 + step**2 / 12)
    assert out.std() == pytest.approx(expected, rel=_STD_RTOL)
    assert abs(out.mean() - z) < 3 * step / math.sqrt(12) + 3 * sigma / math.sqrt(out.size) + 1e-3


@pytest.mark.parametrize("z", [1.0, 2.0])
def test_noise_alone_and_quantisation_alone(z):
    noise = SensorConfig(quantize=False, angle_noise=False)
    out = np.asarray(apply_sensor(KEY, _plane(z), INTR, noise))[:, 4:-4, 4:-4]
    assert out.std() == pytest.approx(noise.sigma_z(z), rel=0.05)
    levels = np.unique(np.asarray(apply_sensor(KEY, _plane(z), INTR, SensorConfig.ideal().replace(
        quantize=True))))
    assert len(levels) == 1 and abs(levels[0] - z) <= SensorConfig().depth_step(z) / 2 * 1.01


def test_quantisation_step_grows_as_z_squared():
    config = SensorConfig.ideal().replace(quantize=True)
    steps = []
    for z in (1.0, 2.0, 3.0):
        ramp = jnp.linspace(z - 0.05, z + 0.05, INTR.width * INTR.height).reshape(1, INTR.height, INTR.width)
        levels = np.unique(np.asarray(apply_sensor(KEY, ramp, INTR, config)))
        step = np.median(np.diff(levels))
        assert step == pytest.approx(config.depth_step(z), rel=0.05)
        steps.append(step)
    assert steps[1] / steps[0] == pytest.approx(4.0, rel=0.1)
    assert steps[2] / steps[0] == pytest.approx(9.0, rel=0.1)


def test_dropout_at_discontinuities_not_on_flat_interior():
    config = SensorConfig.ideal().replace(edge_dropout=True)
    depth = _step_scene()
    out = np.asarray(apply_sensor(KEY, jnp.asarray(depth), INTR, config))[0]
    dropped = (out == 0) & (depth[0] > 0)
    # the box outline, inside and outside, and both rims of the hole
    for row, col in [(14, 20), (13, 20), (33, 20), (34, 20), (20, 16), (20, 15), (20, 39), (20, 40),
                     (20, 51), (20, 58)]:
        assert dropped[row, col], f"edge pixel ({row}, {col}) kept"
    interior = np.zeros_like(dropped)
    interior[17:31, 19:37] = True  # box interior
    interior[2:8, 2:60] = True  # plane far from any edge
    assert not np.any(dropped & interior)
    assert np.all(out[depth[0] == 0] == 0)
    wide = np.asarray(apply_sensor(KEY, jnp.asarray(depth), INTR, config.replace(edge_width=3)))[0]
    assert np.sum(wide == 0) > np.sum(out == 0) and wide[14 - 2, 20] == 0 and wide[17, 20] > 0


def _tilted_plane(tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """[1, H, W] depth of the plane through (0, 0, 1) m whose normal leans ``tilt_deg`` from the optical
    axis about the camera x axis (0 where it is behind the camera), and [H, W] true |cos| incidence."""
    a = math.radians(tilt_deg)
    normal = np.array([0.0, math.sin(a), -math.cos(a)])
    u = (np.arange(INTR.width) - INTR.cx) / INTR.fx
    v = (np.arange(INTR.height) - INTR.cy) / INTR.fy
    rays = np.stack([*np.meshgrid(u, v), np.ones((INTR.height, INTR.width))], -1)
    with np.errstate(divide="ignore"):
        z = (normal @ [0.0, 0.0, 1.0]) / (rays @ normal)
    depth = np.where((z > 0) & (z < 20), z, 0.0)[None].astype(np.float32)
    cos = np.abs(rays @ normal) / np.linalg.norm(rays, axis=-1)
    return depth, cos


@pytest.mark.parametrize("tilt_deg", [0.0, 45.0, 70.0, 85.0])
def test_incidence_from_depth_gradients_is_exact_on_planes(tilt_deg):
    from jaxcls.world.render.sensor import _cos_incidence

    depth, cos = _tilted_plane(tilt_deg)
    ours = np.asarray(_cos_incidence(jnp.asarray(depth), INTR))[0]
    valid = depth[0] > 0
    assert valid.sum() > 1000
    np.testing.assert_allclose(ours[valid], cos[valid], atol=2e-3)


def test_dropout_at_grazing_incidence():
    config = SensorConfig.ideal().replace(grazing_dropout=True)
    limit = math.cos(math.radians(config.max_incidence_deg))
    for tilt_deg in (30.0, 70.0, 84.0):
        depth, cos = _tilted_plane(tilt_deg)
        out = np.asarray(apply_sensor(KEY, jnp.asarray(depth), INTR, config))[0]
        valid = depth[0] > 0
        interior = valid.copy()
        interior[[0, -1], :] = interior[:, [0, -1]] = False
        grazing = cos < limit
        if tilt_deg == 30.0:
            assert not np.any(grazing[valid]) and np.all(out[valid] == depth[0][valid])
        else:
            assert np.sum(grazing & interior) > 100 and np.sum(~grazing & interior) > 100
        # pixels near the threshold may go either way at float32 precision
        clear = interior & (np.abs(cos - limit) > 0.01)
        np.testing.assert_array_equal(out[clear] == 0, grazing[clear])


def test_zero_stays_zero_never_nan_and_deterministic():
    depth = jnp.asarray(_step_scene())
    depth = depth.at[0, 0, :10].set(0.0).at[0, 47, :].set(5.0)  # out of range row
    config = SensorConfig(random_dropout=0.05)
    a = np.asarray(apply_sensor(KEY, depth, INTR, config))
    b = np.asarray(apply_sensor(KEY, depth, INTR, config))
    c = np.asarray(apply_sensor(jax.random.PRNGKey(1), depth, INTR, config))
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    assert np.all(a[np.asarray(depth) == 0] == 0)
    assert np.all(a[0, 47] == 0), "beyond max_depth is no return"
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.dtype == np.float32 and a.shape == depth.shape


def test_apply_sensor_under_jit_and_vmap():
    depth = jnp.asarray(np.concatenate([_step_scene(), _step_scene()]))
    jitted = jax.jit(lambda k, d: apply_sensor(k, d, INTR, SensorConfig()))
    out = jitted(KEY, depth)
    keys = jax.random.split(KEY, 2)
    mapped = jax.vmap(lambda k, d: apply_sensor(k, d, INTR, SensorConfig()))(keys, depth)
    assert out.shape == mapped.shape == depth.shape
    assert np.all(np.isfinite(np.asarray(mapped)))
    single = apply_sensor(KEY, depth[0], INTR, SensorConfig())  # [H, W] works too
    assert single.shape == depth.shape[1:]


@pytest.mark.parametrize("shared", [False, True])
def test_pose_noise_is_rigid_with_configured_spread(shared):
    config = SensorConfig(pose_noise=True, pose_rot_sigma_deg=0.5, pose_trans_sigma=0.004,
                          pose_noise_shared=shared)
    eyes = np.random.default_rng(0).normal(size=(4000, 3)) + np.array([0, 0, 2.0])
    T = jnp.asarray(look_at(eyes, np.zeros(3)), jnp.float32)
    noisy = np.asarray(perturb_poses(KEY, T, config))
    T = np.asarray(T)
    assert noisy.shape == T.shape and np.all(is_rigid(noisy))
    dT = np.linalg.inv(T) @ noisy  # the perturbation in the camera frame
    from scipy.spatial.transform import Rotation

    rotvec = Rotation.from_matrix(dT[:, :3, :3].astype(np.float64)).as_rotvec()
    trans = dT[:, :3, 3]
    if shared:
        np.testing.assert_allclose(rotvec, np.broadcast_to(rotvec[0], rotvec.shape), atol=1e-5)
        np.testing.assert_allclose(trans, np.broadcast_to(trans[0], trans.shape), atol=1e-5)
    else:
        np.testing.assert_allclose(rotvec.std(0), math.radians(0.5), rtol=0.1)
        np.testing.assert_allclose(trans.std(0), 0.004, rtol=0.1)
        np.testing.assert_allclose(rotvec.mean(0), 0, atol=math.radians(0.5) * 0.1)


def test_depth_of_the_wrong_size_is_a_clear_error():
    intr = Intrinsics.kinect_v1(0.1)
    for config in (SensorConfig(), SensorConfig.ideal()):
        with pytest.raises(ValueError, match=r"\(2, 30, 40\).*48, 64"):
            apply_sensor(jax.random.PRNGKey(0), np.ones((2, 30, 40), np.float32), intr, config)


@pytest.mark.parametrize("config", [SensorConfig(), SensorConfig(pose_noise=True, random_dropout=0.1)],
                         ids=["depth", "depth_and_poses"])
def test_several_scenes_measured_at_once_are_each_scene_measured_alone(config):
    # measure_scenes (one program for a chunk of scenes) must give every scene the frames and believed poses of
    # measure with that scene's key: Table 1's device chunks and ``jaxcls dataset``'s files agree through it.
    from jaxcls.world.dataset import scene_key
    from jaxcls.world.render.sensor import measure, measure_scenes

    rng = np.random.default_rng(3)
    depth = np.stack([np.concatenate([_step_scene() + z, _step_scene()[:, ::-1] + z]) for z in (0.0, 0.4, 0.9)])
    T = np.asarray(look_at(rng.normal(size=(3 * 2, 3)) + np.array([0, 0, 2.0]), np.zeros(3))).reshape(3, 2, 4, 4)
    keys = [scene_key(11, i) for i in range(3)]
    alone = [measure(k, jnp.asarray(d), t, INTR, config) for k, d, t in zip(keys, depth, T, strict=True)]
    depth_all, T_all = measure_scenes(keys, jnp.asarray(depth), T, INTR, config)
    np.testing.assert_array_equal(np.asarray(depth_all), np.stack([np.asarray(d) for d, _ in alone]))
    np.testing.assert_array_equal(T_all, np.stack([t for _, t in alone]))
    assert T_all.dtype == np.float64 and (np.asarray(depth_all) > 0).mean() > 0.5
    swapped, _ = measure_scenes(keys[::-1], jnp.asarray(depth), T, INTR, config)  # (each scene its own key)
    assert not np.array_equal(np.asarray(swapped[0]), np.asarray(depth_all[0]))
    with pytest.raises(ValueError, match=r"2 keys.*\(3, 2, 48, 64\)"):
        measure_scenes(keys[:2], jnp.asarray(depth), T, INTR, config)
