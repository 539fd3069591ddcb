"""slzcli.geometry: Pose against scipy directly, quaternion conventions, project at the image's edges."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slzcli.geometry import Pose, invert_pose, project, quat_wxyz_to_matrix, transform_points

RNG = np.random.default_rng(7)
ROTS = Rotation.random(200, random_state=3)
_AXES = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 0]])
EDGE = Rotation.from_rotvec(np.pi * _AXES / np.linalg.norm(_AXES, axis=1)[:, None])  # 180 deg turns


def _T(r: Rotation, t: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (*t.shape[:-1], 1, 1))
    T[..., :3, :3] = r.as_matrix()
    T[..., :3, 3] = t
    return T


def test_matrix_quat_round_trips_and_agree_with_scipy() -> None:
    t = RNG.normal(size=(200, 3))
    T = _T(ROTS, t)
    pose = Pose.from_matrix(T)
    q = pose.as_quat()
    assert np.all(q[:, 3] >= 0)                                   # the sign ROS / TUM writers get
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    ref = ROTS.as_quat()                                         # scipy: x, y, z, w
    np.testing.assert_allclose(q, np.where(ref[:, 3:] < 0, -ref, ref), atol=1e-12)
    np.testing.assert_allclose(Pose.from_quat(q, t).as_matrix(), T, atol=1e-12)
    np.testing.assert_allclose(Pose.from_quat(-q, t).as_matrix(), T, atol=1e-12)  # q and -q: one rotation
    for r in EDGE:                                               # 180 deg turns: w = 0, the sign is a choice
        Te = _T(r, np.zeros(3))
        np.testing.assert_allclose(Pose.from_quat(Pose.from_matrix(Te).as_quat(), np.zeros(3)).as_matrix(), Te,
                                   atol=1e-12)


def test_quaternion_order_is_x_y_z_w() -> None:
    """90 deg about z: (0, 0, sin 45, cos 45) in ROS order; turns x into y."""
    s = np.sqrt(0.5)
    R = Pose.from_quat(np.array([0.0, 0.0, s, s]), np.zeros(3)).rotation.as_matrix()
    np.testing.assert_allclose(R @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)
    np.testing.assert_allclose(quat_wxyz_to_matrix(np.array([[s, 0.0, 0.0, s]]))[0], R, atol=1e-12)


def test_from_quat_normalises_and_refuses_zero_and_nan() -> None:
    q = np.array([0.1, -0.2, 0.3, 0.9])
    np.testing.assert_allclose(Pose.from_quat(3 * q, np.zeros(3)).as_quat(), q / np.linalg.norm(q), atol=1e-12)
    for bad in ([0.0, 0, 0, 0], [np.nan, 0, 0, 1]):
        with pytest.raises(ValueError):
            Pose.from_quat(np.array(bad), np.zeros(3))


def test_wxyz_formula_is_scipy_on_unit_quaternions() -> None:
    q = ROTS.as_quat()
    np.testing.assert_allclose(quat_wxyz_to_matrix(q[:, [3, 0, 1, 2]]), ROTS.as_matrix(), atol=1e-12)


def test_compose_inverse_apply_against_matrices() -> None:
    ta, tb = RNG.normal(size=3), RNG.normal(size=3)
    a, b = Pose(ROTS[0], ta), Pose(ROTS[1], tb)
    Ta, Tb = a.as_matrix(), b.as_matrix()
    np.testing.assert_allclose(a.compose(b).as_matrix(), Ta @ Tb, atol=1e-12)
    np.testing.assert_allclose(a.inverse().as_matrix(), np.linalg.inv(Ta), atol=1e-12)
    np.testing.assert_allclose(invert_pose(Ta), np.linalg.inv(Ta), atol=1e-12)
    np.testing.assert_allclose(a.compose(a.inverse()).as_matrix(), np.eye(4), atol=1e-12)
    pts = RNG.normal(size=(50, 3))
    expected = (Ta @ np.c_[pts, np.ones(50)].T).T[:, :3]
    np.testing.assert_allclose(a.apply(pts), expected, atol=1e-12)
    np.testing.assert_allclose(transform_points(Ta, pts), expected, atol=1e-12)
    np.testing.assert_allclose(a.apply(pts[0]), expected[0], atol=1e-12)


K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])


def test_project_in_front_behind_and_outside() -> None:
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 0.0)                                   # camera at (1, 2, 0), looking along +z
    pts = np.array([[1.0, 2.0, 5.0],                             # on the axis: the principal point
                    [1.0, 2.0, -5.0],                            # behind
                    [1.0, 2.0, 0.0],                             # in the camera centre (z = 0)
                    [1.0 + 319.5 / 500 * 5, 2.0, 5.0],           # u = w - 1 exactly: inside
                    [1.0 + 320.6 / 500 * 5, 2.0, 5.0],           # just beyond the right edge
                    [1.0, 2.0 - 239.5 / 500 * 5 - 0.01, 5.0]])   # above the top edge
    with np.errstate(invalid="ignore"):
        uv, inside = project(pts, T, K, (480, 640))
    np.testing.assert_allclose(uv[0], [319.5, 239.5])
    np.testing.assert_allclose(uv[3, 0], 639.0)
    assert inside.tolist() == [True, False, False, True, False, False]
    # A point behind the camera mirrors into the image: only z > 0 keeps it out.
    uv_b, _ = project(np.array([[1.5, 2.5, -5.0]]), T, K, (480, 640))
    assert 0 <= uv_b[0, 0] <= 639 and 0 <= uv_b[0, 1] <= 479
