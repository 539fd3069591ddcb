"""The colours of every picture slz draws (overlays, heat maps, report, results.mcap, plots).

One perceptually uniform colour map for continuous values (viridis: lightness rises with the value,
readable in grey and by the colour-blind), and one fixed set for the verdict of a pixel or site,
from Okabe & Ito's colour-blind-safe palette (2008, "Color Universal Design"): safe = bluish green,
unsafe = vermillion, undecided (no depth, or depth too noisy to vouch for) = grey. The site square is an outline,
white on a black halo, so that the verdict under it stays visible.
"""

from __future__ import annotations

import cv2

RGB = tuple[int, int, int]

COLORMAP = "viridis"                 # matplotlib's name
CV2_COLORMAP = cv2.COLORMAP_VIRIDIS  # the same map in OpenCV

SAFE: RGB = (0, 158, 115)        # Okabe-Ito bluish green
UNSAFE: RGB = (213, 94, 0)       # Okabe-Ito vermillion
UNDECIDED: RGB = (153, 153, 153)  # grey: no depth, or beyond what the frame can vouch for
UNSEEN: RGB = (60, 60, 60)       # dark grey: a cell of the landing map no frame measured
SITE: RGB = (255, 255, 255)      # the Eq. 10 square's line (on a black halo)
HALO: RGB = (0, 0, 0)
POINT: RGB = (255, 255, 255)     # every SLAM map point in view
KEPT: RGB = (86, 180, 233)       # Okabe-Ito sky blue: map points under the mask
CHOSEN: RGB = (240, 228, 66)     # Okabe-Ito yellow: the chosen cluster
REJECTED: RGB = (230, 159, 0)    # Okabe-Ito orange: a site that failed the acceptance test

VERDICTS: tuple[tuple[str, RGB], ...] = (("safe", SAFE), ("unsafe", UNSAFE), ("undecided", UNDECIDED))


def bgr(rgb: RGB) -> tuple[int, int, int]:
    """OpenCV's channel order."""
    return rgb[2], rgb[1], rgb[0]


def hex_of(rgb: RGB) -> str:
    """``#rrggbb`` for HTML and SVG."""
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def rgba01(rgb: RGB, alpha: float = 1.0) -> tuple[float, float, float, float]:
    """0-1 floats (std_msgs/ColorRGBA, matplotlib)."""
    return rgb[0] / 255.0, rgb[1] / 255.0, rgb[2] / 255.0, alpha
