"""Pictures that read at a glance: one colour map, one verdict palette, a legend, label and scale bar."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from slzcli.outputs import images, palette


def test_heat_maps_use_viridis_and_verdicts_the_palette() -> None:
    ramp = np.linspace(0, 1, 256, dtype=np.float32)[None]
    want = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_VIRIDIS)
    assert np.abs(images.heatmap_bgr(ramp).astype(int) - want).max() <= 1
    assert tuple(images.SAFE_BGR) == palette.bgr(palette.SAFE) and tuple(images.UNSAFE_BGR) == palette.bgr(
        palette.UNSAFE)
    assert len({palette.SAFE, palette.UNSAFE, palette.UNDECIDED}) == 3


def test_overlay_tints_undecided_grey_over_any_mask_value() -> None:
    rgb = np.zeros((4, 4, 3), np.uint8)
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    undecided = np.zeros((4, 4), bool)
    undecided[0, 1:3] = True
    mask[0, 2] = True  # safe by the mask but beyond what the frame vouches for: undecided
    img = images.overlay_bgr(rgb, mask, undecided=undecided)
    tint = lambda c: np.round(0.45 * np.array(palette.bgr(c))).astype(int)  # noqa: E731
    assert np.abs(img[0, 0].astype(int) - tint(palette.SAFE)).max() <= 1
    assert np.abs(img[0, 2].astype(int) - tint(palette.UNDECIDED)).max() <= 1
    assert np.abs(img[0, 1].astype(int) - tint(palette.UNDECIDED)).max() <= 1
    assert np.abs(img[1, 1].astype(int) - tint(palette.UNSAFE)).max() <= 1


@pytest.mark.parametrize(("raw", "want"), [(0.3, 0.2), (1.0, 1.0), (4.9, 2.0), (7.0, 5.0), (13.0, 10.0)])
def test_scale_bar_length_is_one_two_or_five(raw: float, want: float) -> None:
    assert images.nice_length_m(raw) == pytest.approx(want)


def test_site_square_is_an_outline_and_the_overlay_is_annotated() -> None:
    h, w = 240, 320
    rgb = np.full((h, w, 3), 128, np.uint8)
    mask = np.zeros((h, w), bool)
    corners = np.array([[200.0, 160.0], [200.0, 80.0], [120.0, 160.0], [120.0, 80.0]])  # ++, +-, -+, --
    plain = images.site_overlay_bgr(rgb, mask)
    drawn = images.site_overlay_bgr(rgb, mask, corners_px=corners, label="frame 7", px_per_m=40.0)
    assert np.array_equal(drawn[120, 160], plain[120, 160])  # inside the square: the verdict, untouched
    assert drawn[78:83, 160].max(axis=0).min() >= 200  # its white line (anti-aliased), on a black halo
    assert drawn[76:85, 160].min() == 0
    changed = np.any(drawn != plain, axis=2)
    assert changed[:16, :40].any()          # frame label, top left
    assert changed[h - 100:, :100].any()    # legend, bottom left
    assert changed[h - 30:, w - 100:].any()  # scale bar, bottom right
    assert not changed[30:60, 230:300].any()  # elsewhere: nothing drawn
