import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.distance import cdist

from jaxcls import geometry

CENTER = np.array([0.1, -0.2, 0.05])


def test_kinect_intrinsics_match_the_paper():
    intr = geometry.Intrinsics.kinect_v1()
    assert (intr.width, intr.height) == (640, 480)
    assert intr.fx == pytest.approx(525) and intr.fy == pytest.approx(525)
    assert (intr.cx, intr.cy) == (319.5, 239.5)
    assert intr.fovy_deg == pytest.approx(math.degrees(2 * math.atan(240 / 525)))
    assert geometry.CameraConfig().intrinsics() == intr


@pytest.mark.parametrize(("count", "radius", "min_elev"), [(100, 1.0, 0.0), (138, 0.9, 10.0), (7, 0.5, 30.0)])
def test_viewpoints_count_radius_and_look_at_centre(count, radius, min_elev):
    T = geometry.hemisphere_viewpoints(CENTER, count, radius, min_elev)
    assert T.shape == (count, 4, 4) and geometry.is_rigid(T).all()
    eye = T[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(eye - CENTER, axis=1), radius, atol=1e-12)
    elevation = np.degrees(np.arcsin((eye - CENTER)[:, 2] / radius))
    assert elevation.min() >= min_elev
    # The optical axis (camera +z) points at the centre, and image "down" has no upward component.
    forward = T[:, :3, 2]
    np.testing.assert_allclose(forward, (CENTER - eye) / radius, atol=1e-12)
    assert (T[:, 2, 1] <= 1e-12).all()


def test_viewpoints_are_near_uniform():
    eye = geometry.hemisphere_viewpoints(CENTER, 100, 1.0)[:, :3, 3]
    d = cdist(eye, eye)
    np.fill_diagonal(d, np.inf)
    nearest = d.min(axis=1)
    # 100 points on a unit hemisphere (area 2*pi) have a spacing near sqrt(2*pi/100) ~ 0.25.
    assert 0.18 < nearest.mean() < 0.3
    assert nearest.min() > 0.7 * nearest.mean() and nearest.max() < 1.3 * nearest.mean()


def test_look_at_straight_down_is_well_defined():
    T = geometry.look_at([0, 0, 1.0], [0, 0, 0])
    assert geometry.is_rigid(T)
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-12)


def test_look_at_in_jax_matches_numpy_and_has_gradients():
    import jax
    import jax.numpy as jnp

    rng = np.random.default_rng(3)
    eyes, target = rng.normal(size=(6, 3)) + np.array([0, 0, 1.0]), np.array([0.0, 0.1, 0.2])
    np.testing.assert_allclose(np.asarray(geometry.look_at(jnp.asarray(eyes), target, xp=jnp)),
                               geometry.look_at(eyes, target), atol=1e-5)
    grad = jax.grad(lambda e: geometry.look_at(e, jnp.asarray(target), xp=jnp)[:3, 0].sum())(jnp.asarray(eyes[0]))
    assert np.all(np.isfinite(np.asarray(grad))) and np.any(np.asarray(grad) != 0)


def test_backproject_inverts_projection():
    intr = geometry.Intrinsics.kinect_v1(0.1)
    T = geometry.look_at([0.4, -0.3, 0.7], [0.0, 0.05, 0.02])
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 1.5, (intr.height, intr.width))
    world = np.asarray(geometry.backproject(depth, intr, T))
    cam = (world - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(cam[..., 2], depth, rtol=1e-6)
    u, v = intr.project(cam[..., 0], cam[..., 1], 1.0 / cam[..., 2])  # the one pinhole projection
    uu, vv = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    np.testing.assert_allclose(u, uu, atol=1e-4)
    np.testing.assert_allclose(v, vv, atol=1e-4)


def test_mujoco_camera_rotation_and_quaternion():
    T = geometry.look_at([0.3, 0.4, 0.5], [0, 0, 0])
    R = geometry.opencv_to_mujoco_rotation(T[:3, :3])
    np.testing.assert_allclose(R[:, 2], -T[:3, 2])  # MuJoCo cameras look along their -z
    np.testing.assert_allclose(R[:, 1], -T[:3, 1])  # and have y up
    q = geometry.rotation_to_quat(R)
    w, x, y, z = q
    R_back = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    np.testing.assert_allclose(R_back, R, atol=1e-12)


def test_is_rigid_rejects_bad_transforms():
    T = np.eye(4)
    assert geometry.is_rigid(T)
    for bad in (np.diag([1, 1, -1, 1.0]), np.diag([2, 1, 1, 1.0]), np.full((4, 4), np.nan)):
        assert not geometry.is_rigid(bad)
    shear = np.eye(4)
    shear[3, 0] = 1
    assert not geometry.is_rigid(shear)


def test_bad_viewpoint_arguments():
    with pytest.raises(ValueError, match="count"):
        geometry.hemisphere_viewpoints(CENTER, 0)
    with pytest.raises(ValueError, match="min_elevation"):
        geometry.hemisphere_viewpoints(CENTER, 10, 1.0, 95)


def test_yaw_rotation_turns_x_towards_y_about_z():
    from jaxcls.geometry import yaw_rotation

    R = np.asarray(yaw_rotation(np.asarray([0.0, np.pi / 2, 0.3], np.float32)))
    np.testing.assert_allclose(R[1] @ [1.0, 0, 0], [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-7)
    np.testing.assert_allclose(R[2] @ R[2].T, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(R[:, 2], [[0, 0, 1]] * 3, atol=1e-7)


# ---------------------------------------------------------------- jaxlie poses and jaxcls.math


def _random_poses(shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    n = int(np.prod(shape))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = np.random.default_rng(seed).normal(size=(n, 3))
    return T.reshape(*shape, 4, 4)


@pytest.mark.parametrize("shape", [(), (3,), (2, 4)])
def test_pose_from_matrix_round_trips_over_batch_shapes(shape):
    T = _random_poses(shape)
    pose = geometry.pose_from_matrix(T)
    assert isinstance(pose, geometry.SE3) and pose.get_batch_axes() == shape
    np.testing.assert_allclose(np.asarray(pose.as_matrix()), T, atol=1e-6)
    # exp(log(T)) == T, and composing with the inverse gives the identity
    np.testing.assert_allclose(np.asarray(geometry.SE3.exp(pose.log()).as_matrix()), T, atol=2e-6)
    assert pose.log().shape == (*shape, 6)
    np.testing.assert_allclose(np.asarray((pose @ pose.inverse()).as_matrix()), np.broadcast_to(np.eye(4), T.shape),
                               atol=2e-6)


def test_pose_log_puts_translation_before_rotation():
    import jax.numpy as jnp

    tangent = np.asarray(geometry.yaw_pose(0.0, jnp.asarray([0.1, -0.2, 0.3])).log())
    np.testing.assert_allclose(tangent, [0.1, -0.2, 0.3, 0, 0, 0], atol=1e-7)
    tangent = np.asarray(geometry.yaw_pose(0.4, jnp.zeros(3)).log())
    np.testing.assert_allclose(tangent, [0, 0, 0, 0, 0, 0.4], atol=1e-6)


def test_yaw_pose_matches_the_hand_derived_matrix():
    yaw = np.array([[0.0, 0.3, -2.0], [np.pi / 2, np.pi, 1.0]])
    t = np.random.default_rng(1).normal(size=(2, 3, 3))
    T = np.asarray(geometry.yaw_pose(yaw, t).as_matrix())
    c, s = np.cos(yaw), np.sin(yaw)
    expected = np.zeros((2, 3, 4, 4))
    expected[..., 0, 0], expected[..., 0, 1], expected[..., 1, 0], expected[..., 1, 1] = c, -s, s, c
    expected[..., 2, 2] = expected[..., 3, 3] = 1.0
    expected[..., :3, 3] = t
    np.testing.assert_allclose(T, expected, atol=1e-6)
    # a scalar yaw broadcasts over a batch of translations
    assert geometry.yaw_pose(0.5, t).get_batch_axes() == (2, 3)
    np.testing.assert_allclose(np.asarray(geometry.yaw_rotation(yaw)), expected[..., :3, :3], atol=1e-6)
    np.testing.assert_allclose(geometry.yaw_matrix_np(yaw), expected[..., :3, :3], atol=1e-15)


def test_yaw_rotation_has_finite_gradients_at_zero():
    import jax
    import jax.numpy as jnp

    weights = jnp.arange(9.0).reshape(3, 3)
    for yaw in (0.0, 1e-4, np.pi):
        grad = jax.grad(lambda y: jnp.sum(geometry.yaw_rotation(y) * weights))(jnp.float32(yaw))
        # d/dy of sum(W * R(y)) = W00 (-s) + W01 (-c) + W10 c + W11 (-s)
        c, s = np.cos(yaw), np.sin(yaw)
        assert np.isfinite(grad) and float(grad) == pytest.approx(-4 * s - c + 3 * c, abs=1e-5)


def test_rotation_to_quat_is_float64_with_nonnegative_w():
    T = _random_poses((50,), seed=3)
    q = geometry.rotation_to_quat(T[..., :3, :3])
    assert q.dtype == np.float64 and q.shape == (50, 4) and np.all(q[:, 0] >= 0)
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(T[..., :3, :3]).as_quat()
    ref = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1)
    np.testing.assert_allclose(q, ref * np.sign(ref[:, :1]), atol=1e-12)


def test_safe_math_values_and_finite_gradients_at_zero():
    import jax
    import jax.numpy as jnp

    from jaxcls.math import normalize, safe_div, safe_norm

    x = jnp.asarray([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(np.asarray(safe_norm(x)), [5.0, 0.0])
    assert safe_norm(x, keepdims=True).shape == (2, 1)
    np.testing.assert_allclose(np.asarray(normalize(x)), [[0.6, 0.8, 0.0], [0.0, 0.0, 0.0]], atol=1e-7)
    np.testing.assert_allclose(np.asarray(safe_div(jnp.asarray([1.0, 2.0]), jnp.asarray([4.0, 0.0]))), [0.25, 0.0])
    np.testing.assert_allclose(np.asarray(safe_div(1.0, jnp.asarray(0.0), fallback=7.0)), 7.0)

    zero = jnp.zeros(3)
    np.testing.assert_array_equal(np.asarray(jax.grad(safe_norm)(zero)), np.zeros(3))
    np.testing.assert_allclose(np.asarray(jax.grad(safe_norm)(jnp.asarray([3.0, 4.0, 0.0]))), [0.6, 0.8, 0.0])
    jac = np.asarray(jax.jacobian(normalize)(zero))
    assert np.all(np.isfinite(jac))
    num, den = jax.grad(lambda n, d: safe_div(n, d), argnums=(0, 1))(1.0, 0.0)
    assert np.isfinite(num) and np.isfinite(den)


def test_camera_config_round_trips_intrinsics():
    from jaxcls.geometry import CameraConfig, Intrinsics

    for scale in (1.0, 0.5, 0.25):
        assert CameraConfig.kinect_v1(scale).intrinsics() == Intrinsics.kinect_v1(scale)
    assert CameraConfig().intrinsics() == Intrinsics.kinect_v1()  # the defaults are the Kinect v1


def test_rotate_and_normal_equations_match_float64_products():
    """``geometry.rotate`` is ``x @ R.T``, ``math.row_dots`` ``x @ M.T`` for any rows M [K, 3] and
    ``math.normal_equations`` (J^T W J, J^T W r), to float32 rounding, over batch shapes (the elementwise forms
    the GPU's move uses instead of 3- and 6-term matrix products)."""
    from jaxcls.math import normal_equations, row_dots

    rng = np.random.default_rng(0)
    R = rng.normal(size=(3, 3)).astype(np.float32)
    J, w, r = (rng.normal(size=s).astype(np.float32) for s in ((200, 6), (200,), (200,)))
    w = np.abs(w)
    J64 = J.astype(np.float64)
    for fused in (None, False, True):  # by the backend, the product, the elementwise form (an accelerator's)
        for shape in ((5, 3), (2, 7, 3)):
            x = rng.normal(size=shape).astype(np.float32)
            np.testing.assert_allclose(np.asarray(geometry.rotate(jnp.asarray(R), jnp.asarray(x), fused)),
                                       x.astype(np.float64) @ R.T.astype(np.float64), rtol=1e-5, atol=1e-5)
            M = rng.normal(size=(10, 3)).astype(np.float32)  # e.g. camera positions: [..., 10] dot products
            got = np.asarray(row_dots(jnp.asarray(x), jnp.asarray(M), fused))
            assert got.shape == (*shape[:-1], 10)
            np.testing.assert_allclose(got, x.astype(np.float64) @ M.T.astype(np.float64), rtol=1e-5, atol=1e-5)
        A, b = normal_equations(jnp.asarray(J), jnp.asarray(w), jnp.asarray(r), fused)
        np.testing.assert_allclose(np.asarray(A), J64.T @ (w[:, None] * J64), rtol=1e-4, atol=1e-3)
        np.testing.assert_allclose(np.asarray(b), J64.T @ (w * r), rtol=1e-4, atol=1e-3)
