"""The detection core on the working grid (issue 18): block floor, score on the block grid, plan filter on blocks.

Close to the ground a pixel covers millimetres; the maps never run finer than
``terrain.limits.finest_block_m`` on the ground, are finished and scored on that block grid, and the
plan-view filter runs on ``mask.plan_samples_per_cell`` samples per footprint cell. These tests hold
the arithmetic of each piece and that the coarse path keeps what matters: nothing safe beside an
obstacle, and the same safe region as every pixel up to its edge.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.scoring import MaskParams, get_scorer, mask_score, plan_block_px, score_maps
from slzcli.scoring.mask import camera_points, column_in_view
from slzcli.terrain.limits import working_scale
from slzcli.terrain.maps import MapParams, frame_maps
from slzcli.terrain.noise import DepthNoise
from slzcli.types import Frame, Intrinsics

K = Intrinsics(fx=462.137, fy=462.137, cx=320.0, cy=240.0, width=640, height=480)
CONFIG = load_config()
BOX_M = 0.4          # side of the box standing on the ground
BOX_H_M = 0.5        # its height


@pytest.mark.parametrize(("altitude", "finest", "want"), [(3.0, 0.025, 3), (1.5, 0.025, 7), (10.0, 0.025, 1),
                                                          (3.0, 0.0, 1)])
def test_blocks_are_never_finer_than_finest_block_m(altitude: float, finest: float, want: int) -> None:
    """Exact depth (the noise alone would allow full resolution): b = floor(finest_block_m x f / z), at
    least 1; finest_block_m = 0 leaves the noise alone to decide."""
    cfg = load_config(None, [f"terrain.limits.finest_block_m={finest}"])
    w = working_scale(DepthNoise.white(0.0, "none"), altitude, K.fx, cfg.terrain, cfg.uav)
    assert w.block_px == want == max(1, math.floor(finest * K.fx / altitude))


def _box_frame(altitude: float, seed: int, a_per_m: float = 0.0015) -> tuple[Frame, np.ndarray]:
    """Level ground straight below at ``altitude`` with a BOX_M box BOX_H_M tall at the image centre, depth
    noise sigma = a z^2; and each pixel's plan distance (m, Chebyshev) to the box's footprint."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(K.width, dtype=np.float64), np.arange(K.height, dtype=np.float64))
    gx, gy = (u - K.cx) * altitude / K.fx, (v - K.cy) * altitude / K.fy      # ground point under each ray
    on_box = (np.abs(gx) <= BOX_M / 2) & (np.abs(gy) <= BOX_M / 2)
    depth = np.where(on_box, altitude - BOX_H_M, altitude)
    depth = (depth + rng.normal(0.0, 1.0, depth.shape) * a_per_m * depth ** 2).astype(np.float32)
    dist = np.maximum(np.maximum(np.abs(gx) - BOX_M / 2, np.abs(gy) - BOX_M / 2), 0.0)
    down = np.diag([1.0, -1.0, -1.0, 1.0])          # camera z along world -z: straight down, world up = -z_camera
    down[2, 3] = altitude
    return Frame(0, 0, np.zeros((K.height, K.width, 3), np.uint8), depth, K, down), dist


def test_maps_on_the_grid_are_the_grid_upsampled() -> None:
    """From 3 m (b = 3 by the floor) the full-resolution maps and score are the grid's, bilinear, and 0 where the
    pixel has no depth; the score on the grid is the scorer's on the grid maps."""
    frame, _ = _box_frame(3.0, 0)
    depth = frame.depth_m.copy()
    depth[100:140, 100:180] = np.nan                                            # a hole
    frame = Frame(0, 0, frame.rgb, depth, K, frame.T_world_camera)
    maps = frame_maps(frame, MapParams.of(CONFIG))
    assert maps.grid is not None and maps.work is not None and maps.grid.block_px == maps.work.block_px >= 3
    gh, gw = maps.grid.valid.shape
    assert (gh, gw) == (K.height // maps.grid.block_px, K.width // maps.grid.block_px)
    valid = np.isfinite(depth)
    for name in maps.NAMES:
        full = getattr(maps, name)
        assert full.shape == depth.shape and not full[~valid].any()
        up = cv2.resize(maps.grid.maps[name], (K.width, K.height), interpolation=cv2.INTER_LINEAR)
        inside = cv2.erode(valid.view(np.uint8), np.ones((9, 9), np.uint8)).view(bool)   # away from the hole
        np.testing.assert_array_equal(full[inside], up[inside])
    scorer = get_scorer(CONFIG.scoring, CONFIG.mask)
    score = score_maps(scorer, maps)
    on_grid = scorer.score_arrays(maps.grid.maps, maps.grid.valid)
    want = cv2.resize(on_grid, (K.width, K.height), interpolation=cv2.INTER_LINEAR)
    known = cv2.resize(maps.grid.valid.view(np.uint8), (K.width, K.height), interpolation=cv2.INTER_NEAREST)
    want[~valid | (known == 0)] = 0.0
    np.testing.assert_array_equal(score, want)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_column_among_some_pixels_is_the_restriction(seed: int) -> None:
    """column_in_view(among=m) is exactly column_in_view() & m (it only skips the work elsewhere)."""
    rng = np.random.default_rng(seed)
    depth = (4.0 + rng.normal(0.0, 0.05, (K.height, K.width))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    among = rng.random(depth.shape) < 0.3
    up = np.array([0.1, -0.3, -0.95])
    pts = camera_points(depth, K)
    full = column_in_view(depth, K, up, 2.0, points=pts)
    np.testing.assert_array_equal(column_in_view(depth, K, up, 2.0, points=pts, among=among), full & among)


def test_plan_block_follows_the_footprint_cell_not_the_margins() -> None:
    """m = floor(cell / (samples x metres per pixel)), cell = footprint / plan_cells_per_footprint; the
    clearance margins (uav.margin_m, the touch-down dispersion) do not move it."""
    cell = max(CONFIG.uav.footprint_m) * CONFIG.mask.margin_factor / CONFIG.mask.plan_cells_per_footprint
    for z in (3.0, 5.0, 10.0):
        want = max(1, math.floor(cell / (CONFIG.mask.plan_samples_per_cell * z / K.fx)))
        depth = np.full((K.height, K.width), z, np.float32)
        assert plan_block_px(depth, K, MaskParams.of(CONFIG)) == want
        wider = load_config(None, ["uav.touchdown_dispersion_m=0.3", "uav.margin_m=0.3"])
        assert plan_block_px(depth, K, MaskParams.of(wider)) == want
    assert plan_block_px(np.full((K.height, K.width), 5.0, np.float32), K,
                         MaskParams.of(load_config(None, ["mask.plan_samples_per_cell=0"]))) == 1    # 0: every pixel


@pytest.mark.parametrize("altitude", [5.0, 8.0])
def test_the_plan_filter_on_blocks_keeps_the_box_clear_and_the_open_ground(altitude: float) -> None:
    """A box on level ground straight below (noise a = 0.0015/m, a D435 at its best), the default blocks
    (m = 3 from 5 m, 2 from 8 m) against every pixel (``plan_samples_per_cell: 0``):
    - exact: with either, no pixel whose ground is closer to the box than half the filter square less one
      plan cell (0.428 - 0.107 m) is safe, and open ground is;
    - the masks differ only at the edge of the safe region, within 1.5 plan cells plus a block of each
      other (the raster's cells start at the first sample, so its cell grid moves by up to a cell between
      samplings). Measured over seeds 0-4, px from the other mask at most: 5 m 9.2 (limit 14.8 + 3 =
      17.8), 8 m 7.4 (limit 9.3 + 2 = 11.3). Safe fraction from 5 m: 0.220-0.224 on blocks, 0.215-0.216
      on every pixel.
    """
    every = load_config(None, ["mask.plan_samples_per_cell=0"])
    cfg = CONFIG
    side = cfg.mask.margin_factor * max(cfg.uav.footprint_m) + 2 * cfg.uav.clearance_m
    cell = side / cfg.mask.plan_cells_per_footprint
    cell_px = cell * K.fx / altitude
    for seed in range(3):
        frame, dist = _box_frame(altitude, seed)
        masks = []
        for c in (cfg, every):
            scorer = get_scorer(c.scoring, c.mask)
            maps = frame_maps(frame, MapParams.of(c))
            sm = mask_score(scorer, score_maps(scorer, maps), frame.depth_m, K, MaskParams.of(c), maps.work,
                            maps.up_camera)
            assert not sm.mask[dist < side / 2 - cell].any()
            assert sm.mask.mean() > 0.1                     # open ground is called safe
            masks.append(sm.mask)
        m = plan_block_px(frame.depth_m, K, MaskParams.of(cfg))
        assert plan_block_px(frame.depth_m, K, MaskParams.of(every)) == 1 < m
        blocks, pixels = masks
        to_pixels = cv2.distanceTransform((~pixels).view(np.uint8), cv2.DIST_L2, 5)   # px to the every-pixel mask
        to_blocks = cv2.distanceTransform((~blocks).view(np.uint8), cv2.DIST_L2, 5)
        assert to_pixels[blocks].max(initial=0.0) <= 1.5 * cell_px + m
        assert to_blocks[pixels].max(initial=0.0) <= 1.5 * cell_px + m
