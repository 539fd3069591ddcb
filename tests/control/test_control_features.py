"""Image-moment features (Eqs. 32-37, 65-66) on a level square."""

from __future__ import annotations

import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.control import features as ft
from slzcli.control.dynamics import enu_to_ned
from slzcli.landing.corners import square_corners

F = 462.137
Z_STAR = 2.0


@pytest.fixture
def corners_ned() -> np.ndarray:
    return enu_to_ned(square_corners(np.array([1.0, -0.5, 0.0]), (0.656, 0.656)))


@pytest.mark.parametrize("depth", [2.0, 3.5, 10.0])
@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.0])
def test_level_square_features_are_centroid_over_desired_depth(corners_ned: np.ndarray, depth: float,
                                                                yaw: float) -> None:
    a_d = ft.desired_area(corners_ned, F, Z_STAR)
    cam = np.array([[0.3, 1.4, -depth]])  # NED: depth m above the ground (z = 0)
    p_v = ft.virtual_points(corners_ned, cam, np.array([yaw]))
    q = ft.features(ft.virtual_pixels(p_v, F), a_d, F)[0]
    centroid_v = p_v[0].mean(axis=0)
    assert q[2] == pytest.approx(depth / Z_STAR, rel=1e-9)
    assert q[0] == pytest.approx(centroid_v[0] / Z_STAR, rel=1e-9)
    assert q[1] == pytest.approx(centroid_v[1] / Z_STAR, rel=1e-9)
    # and the centroid in V is the world offset turned by -yaw
    rel = corners_ned.mean(axis=0) - cam[0]
    c, s = np.cos(yaw), np.sin(yaw)
    assert centroid_v[:2] == pytest.approx([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1]])


def test_square_moments_are_isotropic_and_a_scales_with_inverse_depth_squared(corners_ned: np.ndarray) -> None:
    cam = corners_ned.mean(axis=0)[None] - np.array([0.0, 0.0, 4.0])
    uv = ft.virtual_pixels(ft.virtual_points(corners_ned, cam, np.array([0.0])), F)
    m = ft.moments(uv)
    assert m.mu20[0] == pytest.approx(m.mu02[0])
    assert m.mu11[0] == pytest.approx(0.0, abs=1e-9)  # Eq. 65 is undefined: the line feature is used
    assert ft.desired_area(corners_ned, F, 2.0) / m.a[0] == pytest.approx(4.0)


def test_yaw_feature_is_the_corner_line_angle_and_turns_against_the_body(corners_ned: np.ndarray) -> None:
    cam = corners_ned.mean(axis=0)[None] - np.array([0.0, 0.0, 3.0])
    base = ft.yaw_feature(ft.virtual_pixels(ft.virtual_points(corners_ned, cam, np.array([0.0])), F))[0]
    d = corners_ned[1] - corners_ned[0]
    assert base == pytest.approx(np.arctan2(d[1], d[0]))
    turned = ft.yaw_feature(ft.virtual_pixels(ft.virtual_points(corners_ned, cam, np.array([0.3])), F))[0]
    assert ft.wrap_angle(turned - base) == pytest.approx(-0.3)  # q_psi' = -psi'


def test_real_camera_sees_a_square_below_centred_and_misses_one_far_away(corners_ned: np.ndarray) -> None:
    cam = ft.CameraModel.from_config(load_config().camera, load_config().uav)
    r_ic = np.eye(3)[None] @ cam.R_BC  # level body, heading north
    t_ic = corners_ned.mean(axis=0)[None] - np.array([0.0, 0.0, 3.0])
    uv, depth = ft.camera_pixels(corners_ned, r_ic, t_ic, cam)
    assert uv[0].mean(axis=0) == pytest.approx([cam.cx, cam.cy])
    assert (depth > 0).all() and ft.in_image(uv, depth, cam)[0]
    far = t_ic + np.array([20.0, 0.0, 0.0])
    uv, depth = ft.camera_pixels(corners_ned, r_ic, far, cam)
    assert not ft.in_image(uv, depth, cam)[0]
    # image top = nose: a point ahead (north) of the camera appears above the centre
    ahead = corners_ned.mean(axis=0)[None] + np.array([1.0, 0.0, 0.0])
    uv, _ = ft.camera_pixels(ahead, r_ic, t_ic, cam)
    assert uv[0, 0, 1] < cam.cy and uv[0, 0, 0] == pytest.approx(cam.cx)
