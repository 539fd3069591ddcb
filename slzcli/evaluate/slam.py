"""Trajectory accuracy against ground truth: ATE and RPE after Umeyama alignment (pure functions).

Estimated and true poses are T_world_camera (4x4) of the same frames, each in its own world
frame; SE(3) alignment removes that frame difference (Sim(3) also a scale, for monocular).
Conventions follow Sturm et al. 2012 (TUM RGB-D benchmark): ATE = RMSE of position after
alignment; RPE over a frame delta = RMSE of the translational (and rotational) drift.

Map segments: after a SLAM map reset the estimated poses are in a new world frame
(``slzcli.slam.segments``), so one alignment over the whole run would fit two unrelated
frames at once. ``ate_by_segment`` aligns each segment on its own and gives each one's ATE
and a combined figure (the RMSE over every aligned frame); RPE pairs never straddle two
segments.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Alignment:
    """x_gt ~ scale * R @ x_est + t."""

    R: np.ndarray
    t: np.ndarray
    scale: float

    def apply(self, T: np.ndarray) -> np.ndarray:
        """Aligned copies of poses (..., 4, 4); positions scaled, rotations composed."""
        out = np.array(T, dtype=np.float64, copy=True)
        out[..., :3, :3] = self.R @ out[..., :3, :3]
        out[..., :3, 3] = self.scale * out[..., :3, 3] @ self.R.T + self.t
        return out


@dataclass(frozen=True)
class AteResult:
    rmse_m: float
    mean_m: float
    max_m: float
    n: int
    alignment: Alignment


@dataclass(frozen=True)
class RpeResult:
    trans_rmse_m: float
    rot_rmse_deg: float
    delta: int
    n: int


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> Alignment:
    """Least-squares (R, t, s) with dst ~ s R src + t (Umeyama 1991). src, dst: (N,3), N >= 3."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (N,3) arrays with N >= 3, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs ** 2).sum() / len(src)
    scale = float(np.trace(np.diag(D) @ S) / var_s) if with_scale and var_s > 0 else 1.0
    t = mu_d - scale * R @ mu_s
    return Alignment(R, t, scale)


def _stack(poses: Sequence[np.ndarray | None]) -> np.ndarray:
    return np.stack([np.asarray(p, float) for p in poses]) if len(poses) else np.zeros((0, 4, 4))


def paired(estimated: Sequence[np.ndarray | None], truth: Sequence[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """The frames where both poses exist, as two (N,4,4) arrays."""
    if len(estimated) != len(truth):
        raise ValueError(f"{len(estimated)} estimated poses but {len(truth)} true ones")
    keep = [i for i, (e, g) in enumerate(zip(estimated, truth, strict=True)) if e is not None and g is not None]
    return _stack([estimated[i] for i in keep]), _stack([truth[i] for i in keep])


def ate(estimated: Sequence[np.ndarray | None], truth: Sequence[np.ndarray | None],
        with_scale: bool = False) -> AteResult:
    """Absolute trajectory error over frames with both poses, after SE(3) (or Sim(3)) alignment."""
    E, G = paired(estimated, truth)
    if len(E) < 3:
        raise ValueError(f"ATE needs at least 3 frames with both poses, got {len(E)}")
    al = umeyama(E[:, :3, 3], G[:, :3, 3], with_scale)
    err = np.linalg.norm(al.apply(E)[:, :3, 3] - G[:, :3, 3], axis=1)
    return AteResult(float(np.sqrt(np.mean(err ** 2))), float(err.mean()), float(err.max()), len(E), al)


@dataclass(frozen=True)
class SegmentedAte:
    """ATE per map segment (each aligned on its own) and combined: the RMSE over all their frames.

    Segments with fewer than 3 frames with both poses cannot be aligned: they are in ``skipped``
    (segment -> frames) and not in the combined figure.
    """

    per_segment: dict[int, AteResult]
    skipped: dict[int, int]
    rmse_m: float
    n: int


def ate_by_segment(estimated: Sequence[np.ndarray | None], truth: Sequence[np.ndarray | None],
                   segments: Sequence[int], with_scale: bool = False) -> SegmentedAte:
    """``ate`` of each map segment on its own (one alignment each) and the combined RMSE."""
    if not len(estimated) == len(truth) == len(segments):
        raise ValueError(f"{len(estimated)} estimated poses, {len(truth)} true ones, {len(segments)} segments")
    per: dict[int, AteResult] = {}
    skipped: dict[int, int] = {}
    for k in sorted({int(s) for s, e in zip(segments, estimated, strict=True) if e is not None}):  # a few maps
        mine = [e if s == k else None for e, s in zip(estimated, segments, strict=True)]
        n = sum(e is not None and g is not None for e, g in zip(mine, truth, strict=True))
        if n < 3:
            skipped[k] = n
            continue
        per[k] = ate(mine, truth, with_scale)
    if not per:
        raise ValueError("ATE needs at least 3 frames with both poses in one map segment")
    n_all = sum(r.n for r in per.values())
    rmse = float(np.sqrt(sum(r.n * r.rmse_m ** 2 for r in per.values()) / n_all))
    return SegmentedAte(per, skipped, rmse, n_all)


def rpe(estimated: Sequence[np.ndarray | None], truth: Sequence[np.ndarray | None], delta: int = 1,
        segments: Sequence[int] | None = None) -> RpeResult:
    """Relative pose error between frames i and i+delta where all four poses exist (no alignment needed).

    With ``segments`` (each frame's map segment), pairs from two different segments are left out.
    """
    if len(estimated) != len(truth):
        raise ValueError(f"{len(estimated)} estimated poses but {len(truth)} true ones")
    same = (lambda i: segments[i] == segments[i + delta]) if segments is not None else (lambda i: True)
    idx = [i for i in range(len(truth) - delta)
           if all(p is not None for p in (estimated[i], estimated[i + delta], truth[i], truth[i + delta]))
           and same(i)]
    if not idx:
        raise ValueError(f"RPE needs at least one pair of frames {delta} apart with both poses")
    E0, E1 = _stack([estimated[i] for i in idx]), _stack([estimated[i + delta] for i in idx])
    G0, G1 = _stack([truth[i] for i in idx]), _stack([truth[i + delta] for i in idx])
    dE = np.linalg.inv(E0) @ E1
    dG = np.linalg.inv(G0) @ G1
    err = np.linalg.inv(dG) @ dE
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    cos = np.clip((np.trace(err[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    rot = np.degrees(np.arccos(cos))
    return RpeResult(float(np.sqrt(np.mean(trans ** 2))), float(np.sqrt(np.mean(rot ** 2))), delta, len(idx))
