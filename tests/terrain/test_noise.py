"""Depth noise measured from the depth (terrain/noise.py) and the limits derived from it (terrain/limits.py).

Accuracy limits here were measured over the seeds each test runs (see the comments); the
estimator pools ~300k residuals per 640x480 frame, so its scatter is small.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.terrain import maps as tm
from slzcli.terrain.limits import edge_scaling_m, limit_reason, vouchable_altitude_m, working_scale
from slzcli.terrain.noise import SCALES_PX, DepthNoise, NoiseTracker, estimate_noise
from slzcli.types import Intrinsics

CONFIG = load_config()
NE = CONFIG.terrain.noise_estimate
CAM = CONFIG.camera
K = Intrinsics(CAM.fx, CAM.fy, CAM.cx, CAM.cy, CAM.width, CAM.height)
F = 0.5 * (K.fx + K.fy)
DOWN = np.array([0.0, 0.0, -1.0])


def plane(z_m: float, tilt_deg: float = 0.0) -> np.ndarray:
    """Depth of a plane z_m ahead on the optical axis, tilted about the camera's x axis."""
    v = (np.arange(K.height, dtype=np.float64)[:, None] - K.cy) / K.fy
    t = math.tan(math.radians(tilt_deg))
    return np.broadcast_to(z_m / (1.0 - t * v), (K.height, K.width)).astype(np.float64)


def noisy(depth: np.ndarray, a: float, seed: int, corr_px: float = 0.0) -> np.ndarray:
    """sigma_z = a z^2 per pixel; ``corr_px`` > 0 correlates it (Gaussian-filtered, rescaled)."""
    n = np.random.default_rng(seed).standard_normal(depth.shape).astype(np.float32)
    if corr_px > 0:
        n = cv2.GaussianBlur(n, (0, 0), corr_px).astype(np.float32, copy=False)
        n /= n.std()
    return (depth + a * depth * depth * n).astype(np.float32)


# ----------------------------------------------------------------------------- estimate
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("z_m,tilt_deg", [(3.0, 0.0), (10.0, 0.0), (6.0, 30.0)])
@pytest.mark.parametrize("a", [0.0005, 0.003])
def test_white_noise_is_measured_at_every_range_and_tilt(seed: int, z_m: float, tilt_deg: float, a: float) -> None:
    est = estimate_noise(noisy(plane(z_m, tilt_deg), a, seed), NE)
    assert est is not None and est.source == "estimated"
    # measured over these 3 seeds x 6 planes: |error| <= 0.36 % at b = 1, <= 3.2 % at b <= 8 (limits 2 %, 6 %)
    assert est.a1_per_m == pytest.approx(a, rel=0.02)
    for b, ab in zip(SCALES_PX[:4], est.a_per_m[:4], strict=True):
        assert ab == pytest.approx(a / b, rel=0.06), b     # averaging b x b white pixels divides by b


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_correlated_noise_is_not_credited_with_averaging(seed: int) -> None:
    """Noise correlated over ~2 px (like a stereo matcher's) does not fall with block size as white noise does."""
    est = estimate_noise(noisy(plane(8.0), 0.002, seed, corr_px=2.0), NE)
    white = estimate_noise(noisy(plane(8.0), 0.002, seed), NE)
    assert est is not None and white is not None
    # measured over seeds 0-2: correlated a_8 is 4.6-4.7x white a_8, and 4.9-5.1x its own a_1 (the pixel
    # scale sees only the high frequencies of a smooth error); limits 3x and 3x
    assert est.a_per_m[3] > 3 * white.a_per_m[3]
    assert est.a_per_m[3] > 3 * est.a_per_m[0]


def test_edges_and_holes_do_not_inflate_the_estimate() -> None:
    depth = plane(10.0)
    depth[:, 300:420] -= 1.0                               # a 1 m high box
    d = noisy(depth, 0.001, 3)
    d[np.random.default_rng(4).random(d.shape) < 0.05] = np.nan   # 5 % scattered holes
    est = estimate_noise(d, NE)
    assert est is not None
    assert est.a1_per_m == pytest.approx(0.001, rel=0.05)  # measured 0.96 % off


def test_too_little_depth_gives_no_estimate_and_the_tracker_falls_back() -> None:
    empty = np.full((K.height, K.width), np.nan, np.float32)
    assert estimate_noise(empty, NE) is None
    tracker = NoiseTracker("auto", NE)
    prior = tracker.update(empty)
    assert prior.source == "prior" and prior.a_per_m == (NE.prior_a_per_m,) * len(SCALES_PX)
    first = tracker.update(noisy(plane(5.0), 0.002, 0))
    assert first.a1_per_m == pytest.approx(0.002, rel=0.02)
    again = tracker.update(empty)                          # an empty frame keeps the recent estimate
    assert again.a1_per_m == pytest.approx(first.a1_per_m)
    assert tracker.summary()["frames_on_prior"] == 1


def test_tracker_smooths_with_a_running_median_and_a_number_overrides() -> None:
    tracker = NoiseTracker("auto", dataclasses.replace(NE, frames=3))
    for a in (0.001, 0.001, 0.01, 0.001):                  # one odd frame cannot swing the windows
        got = tracker.update(noisy(plane(5.0), a, 0))
    assert got.a1_per_m == pytest.approx(0.001, rel=0.03)
    fixed = NoiseTracker(0.004, NE).update(noisy(plane(5.0), 0.001, 0))
    assert fixed.source == "config" and fixed.a_per_m[2] == pytest.approx(0.001)


def test_terrain_noise_is_auto_or_a_number() -> None:
    assert load_config(overrides=["terrain.noise=0.002"]).terrain.noise == 0.002
    from slzcli.errors import ConfigError
    with pytest.raises(ConfigError, match=r"terrain\.noise.*'auto' or a number"):
        load_config(overrides=["terrain.noise=high"])


# ----------------------------------------------------------------------------- limits
def test_exact_depth_keeps_the_paper_windows() -> None:
    w = working_scale(DepthNoise.white(0.0, "none"), 10.0, F, CONFIG.terrain, CONFIG.uav)
    assert w.block_px == 1 and w.vouched and w.step_min_m == 0.0
    assert w.slope_window_blocks == tm.normal_window_px(np.full((48, 64), 10.0, np.float32), K,
                                                        CONFIG.terrain.steepness)
    flat = CONFIG.terrain.flatness
    # exact depth: a step the UAV cannot tolerate (uav.max_step_m) is exactly a strong Canny edge
    assert w.metres_per_level == edge_scaling_m(CONFIG.uav.max_step_m, 0.0, 3.0, flat.canny_low, flat.canny_high,
                                                flat.blur_px)
    step = plane(10.0).astype(np.float32)
    step[:, 320:] -= CONFIG.uav.max_step_m * 1.05
    assert tm.depth_edges(step, flat, w.metres_per_level)[100:380, 318:322].any()
    step[:, 320:] += CONFIG.uav.max_step_m * 0.1      # a step of 0.55 max_step is at most a weak edge
    assert not tm.depth_edges(step, flat, w.metres_per_level)[100:380].any()


def test_windows_grow_with_the_noise_and_the_limits_follow_it() -> None:
    prev = None
    for a in (0.0, 0.0005, 0.0015, 0.003):
        w = working_scale(DepthNoise.white(a, "config"), 10.0, F, CONFIG.terrain, CONFIG.uav)
        if prev is not None:
            assert w.block_px >= prev.block_px and w.step_min_m > prev.step_min_m
        prev = w
    # white 0.003 at 10 m (sigma 0.3 m): blocks of 10 px, 3 blocks across the footprint, steps of
    # 6 cm and slopes of 10 deg distinguishable at 3 sigma: within the UAV's 9 cm and 15 deg
    assert prev is not None and prev.block_px == 10 and prev.vouched
    assert prev.step_min_m == pytest.approx(0.0600, abs=0.002)


def test_correlated_noise_is_refused_where_white_noise_of_the_same_sigma_is_not() -> None:
    white = DepthNoise.white(0.0035, "config")
    stereo = DepthNoise.flat(0.0035, "prior")              # averaging does not help
    assert working_scale(white, 10.0, F, CONFIG.terrain, CONFIG.uav).vouched
    w = working_scale(stereo, 10.0, F, CONFIG.terrain, CONFIG.uav)
    assert not w.vouched and w.step_min_m > CONFIG.uav.max_step_m
    reason = limit_reason(w, CONFIG.terrain, CONFIG.uav)
    assert reason.startswith("at 10.0 m the depth noise (sigma ~ 0.35 m) hides steps below")
    below = vouchable_altitude_m(stereo, F, CONFIG.terrain, CONFIG.uav, 10.0)
    assert below is not None and f"below {below:.1f} m it would not" in reason
    assert working_scale(stereo, below * 0.98, F, CONFIG.terrain, CONFIG.uav).vouched
    assert not working_scale(stereo, below * 1.02, F, CONFIG.terrain, CONFIG.uav).vouched


def test_vouch_depth_scales_as_the_limits_do() -> None:
    w = working_scale(DepthNoise.white(0.0015, "config"), 6.0, F, CONFIG.terrain, CONFIG.uav)
    assert w.vouched and w.vouch_depth_m > w.altitude_m
    ratio = w.vouch_depth_m / w.altitude_m                 # h ~ z^2, slope ~ z with the same pixel windows
    assert ratio == pytest.approx(min(math.sqrt(w.max_step_m / w.step_min_m), w.max_slope_deg / w.slope_min_deg))


# ----------------------------------------------------------------------------- maps under noise
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_level_ground_at_10_m_under_heavy_white_noise_scores_safe_and_a_kerb_does_not(seed: int) -> None:
    """Level ground 10 m below, sigma = 0.003 z^2 = 0.3 m, with a 0.15 m kerb 1 m wide across it."""
    depth = plane(10.0)
    x = (np.arange(K.width) - K.cx) / K.fx * 10.0
    kerb = np.abs(x - 2.0) < 0.5
    depth[:, kerb] -= 0.15
    d = noisy(depth, 0.003, seed)
    noise = estimate_noise(d, NE)
    assert noise is not None
    work = tm.frame_working(d, K, noise, CONFIG.terrain, CONFIG.uav)
    assert work is not None and work.vouched
    maps = tm.compute_maps(d, K, DOWN, CONFIG.terrain, work, noise)
    from slzcli.scoring import MaskParams, get_scorer, score_frame
    sm = score_frame(get_scorer(CONFIG.scoring, CONFIG.mask), maps, d, K, MaskParams.of(CONFIG))
    far = np.abs(x + 3.0) < 1.0                            # 4-6 m from the kerb
    rows = slice(100, 380)
    # measured over seeds 0-2: 100 % of the far ground safe, 0 % within 1 m of the kerb (limits 90 %, 0 within 0.3 m)
    assert sm.mask[rows][:, far].mean() > 0.9
    assert not sm.mask[rows][:, np.abs(x - 2.0) < 0.8].any()


# ----------------------------------------------------------------------------- fast forms, same bits
def test_pyramid_sums_and_quantum_match_their_direct_forms() -> None:
    """The 2 x 2 block sums equal numpy's reshape-sum bit for bit, and the depth quantum the gathered
    minimum, on float32 depth with holes and on odd-sized crops."""
    from slzcli.terrain.noise import _sum_2x2, depth_quantum_m

    rng = np.random.default_rng(3)
    for shape in ((480, 640), (241, 333), (60, 80)):
        a = (rng.random(shape) * 7).astype(np.float32)
        h, w = shape[0] // 2 * 2, shape[1] // 2 * 2
        np.testing.assert_array_equal(_sum_2x2(a[:h, :w]), a[:h, :w].reshape(h // 2, 2, w // 2, 2).sum(axis=(1, 3)))
        depth = np.round(a * 1000) / np.float32(1000)
        depth[rng.random(shape) < 0.1] = np.nan
        valid = np.isfinite(depth) & (depth > 0)
        both = valid[:, 1:] & valid[:, :-1]
        dz = np.abs(depth[:, 1:] - depth[:, :-1])[both]
        assert depth_quantum_m(depth, valid) == float(dz[dz > 0].min())
    flat = np.full((20, 30), 2.0, np.float32)
    assert depth_quantum_m(flat, np.isfinite(flat)) == 0.0
