"""The region the fused method judges on a detection frame (``FusedTerrain.maps_in_view``): the cells the frame
saw and two landing squares around them, never wider than the square around the camera it replaced."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fusion_scene import INTR, Block, exact_depth, fly, pose

from slzcli.fusion.session import pixel_cells


@pytest.mark.parametrize("seed", range(3))
def test_every_pixel_with_depth_falls_in_the_region_and_it_is_smaller_than_the_square(seed: int) -> None:
    """Flown at 8 m: every pixel of the last frame with depth has its cell in the region (the mask covers the whole
    view), the region spans the view plus at most two landing squares a side, and it holds fewer cells than the
    square of 2.5 depths around the camera (the D435-like view here is 1.2 x 0.9 depths)."""
    block = Block(-0.5, 0.5, -0.4, 0.4, 0.3)
    *_, (i, ft, _) = fly([], a_per_m=0.002, white=0.3, corr_px=3.0, seed=seed, frames=12, step_m=0.3, block=block)
    fm = ft.maps_in_view()
    assert fm is not None and ft.view is not None
    T = pose(-0.5 * 0.3 * 11 + 0.3 * i, 0.0, 8.0)
    depth = exact_depth(T, block)
    index = pixel_cells(fm, depth, INTR, T)
    ny, nx = fm.region.shape
    assert np.all(index[np.isfinite(depth) & (depth > 0)] < nx * ny)
    pad = math.ceil(2 * ft.params.square_m / ft.params.cell_m)
    vx0, vy0, vx1, vy1 = ft.view
    assert nx <= vx1 - vx0 + 1 + 2 * pad and ny <= vy1 - vy0 + 1 + 2 * pad
    square = math.ceil((2.5 * ft.depth_m + 4 * ft.params.square_m) / ft.params.cell_m)
    assert nx * ny < 0.8 * square * square
