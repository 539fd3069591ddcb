"""Monte Carlo batches compared run by run: a start, a target, and one run's values out of a batch."""

from __future__ import annotations

import numpy as np

from slzcli.control.simulate import SimResult, Target
from slzcli.landing.corners import square_corners

BASE = np.array([0.0, 0.0, 3.0, 0.0])
PER_RUN = ("reason", "success", "stabilisation_time_s", "settling_time_s", "switch_time_s", "final_feature_error_px",
           "final_yaw_error_deg", "touchdown_error_m", "touchdown_speed_m_s", "max_tilt_deg", "landing_time_s",
           "starts_world")


def target() -> Target:
    """A 0.656 m square site at the origin."""
    c = np.zeros(3)
    return Target(c, square_corners(c, (0.656, 0.656)))


def run_values(r: SimResult, i: int) -> dict[str, np.ndarray]:
    """Run ``i``'s values (every per-run field) out of a batch."""
    return {name: getattr(r, name)[i] for name in PER_RUN}


def same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Two runs' values equal bit for bit (NaN equal to NaN)."""
    return all(np.array_equal(a[k], b[k], equal_nan=np.asarray(a[k]).dtype.kind == "f") for k in a)
