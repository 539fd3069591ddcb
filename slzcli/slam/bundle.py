"""Local bundle adjustment for the built-in odometry: keyframe poses and map points, robust loss.

Why: points triangulated between two keyframes carry depth errors of several cm at 4 m (0.3 m
baseline), and poses tracked on them pass those errors on; without a joint refinement the error
grows with every keyframe and depends chaotically on which features happen to have depth (issue 14).
Residuals are the reprojection error of every observation (px) and, where the sensor measured a
depth, the depth error in units of its noise (relative to range) so that depth keeps metric scale.
A Huber loss caps the pull of mismatches. Pure function of arrays, vectorised over observations
(analytic Jacobians, points eliminated per point by the Schur complement: no sparse solver needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BundleResult:
    poses_cw: np.ndarray     # (P,4,4) refined T_camera_world (fixed ones unchanged)
    xyz: np.ndarray          # (Q,3) refined points
    reproj_px: np.ndarray    # (N,) reprojection error of each observation after refinement
    cost_before: float
    cost_after: float


def rotate(rvec: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rows of ``x`` rotated by the axis-angle rows of ``rvec`` (Rodrigues, vectorised)."""
    theta = np.linalg.norm(rvec, axis=1, keepdims=True)
    small = theta < 1e-12
    k = np.where(small, 0.0, rvec / np.where(small, 1.0, theta))
    c, s = np.cos(theta), np.sin(theta)
    return x * c + np.cross(k, x) * s + k * np.sum(k * x, axis=1, keepdims=True) * (1.0 - c)


def _skew(v: np.ndarray) -> np.ndarray:
    """(N,3,3) cross-product matrices of rows of v."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1), np.stack([v[:, 2], z, -v[:, 0]], -1),
                     np.stack([-v[:, 1], v[:, 0], z], -1)], 1)


def _linearise(R: np.ndarray, t: np.ndarray, X: np.ndarray, obs_pose: np.ndarray, obs_point: np.ndarray,
               obs_px: np.ndarray, obs_depth: np.ndarray, K: np.ndarray, depth_sigma_rel: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals (N,3: u, v, depth; depth 0 where unmeasured) and their Jacobians (N,3,6), (N,3,3)."""
    Rn = R[obs_pose]
    pc = np.einsum("nij,nj->ni", Rn, X[obs_point]) + t[obs_pose]
    z = np.maximum(pc[:, 2], 1e-3)
    fx, fy = K[0, 0], K[1, 1]
    has_d = np.isfinite(obs_depth)
    inv_sd = np.where(has_d, 1.0 / (depth_sigma_rel * np.where(has_d, obs_depth, 1.0)), 0.0)
    e = np.stack([fx * pc[:, 0] / z + K[0, 2] - obs_px[:, 0], fy * pc[:, 1] / z + K[1, 2] - obs_px[:, 1],
                  np.where(has_d, pc[:, 2] - np.where(has_d, obs_depth, 0.0), 0.0) * inv_sd], 1)
    Jc = np.zeros((len(pc), 3, 3))  # d residual / d camera-frame point
    Jc[:, 0, 0], Jc[:, 0, 2] = fx / z, -fx * pc[:, 0] / z ** 2
    Jc[:, 1, 1], Jc[:, 1, 2] = fy / z, -fy * pc[:, 1] / z ** 2
    Jc[:, 2, 2] = inv_sd
    # pose update T <- exp(d) T: d pc / d rot = -[pc]x, d pc / d trans = I
    J_pose = np.concatenate([-Jc @ _skew(pc), Jc], axis=2)
    J_pt = Jc @ Rn
    return e, J_pose, J_pt


def _huber_weights(e: np.ndarray, k: float) -> np.ndarray:
    """IRLS weights (N,3): on the reprojection error's norm (u, v together) and on the depth term."""
    r = np.linalg.norm(e[:, :2], axis=1)
    w_uv = np.where(r <= k, 1.0, k / np.maximum(r, 1e-12))
    a = np.abs(e[:, 2])
    w_d = np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))
    return np.stack([w_uv, w_uv, w_d], 1)


def _cost(e: np.ndarray, k: float) -> float:
    r = np.linalg.norm(e[:, :2], axis=1)
    return float(np.sum(_huber(r, k)) + np.sum(_huber(e[:, 2], k)))


def bundle_adjust(poses_cw: np.ndarray, fixed: np.ndarray, xyz: np.ndarray, obs_pose: np.ndarray,
                  obs_point: np.ndarray, obs_px: np.ndarray, obs_depth: np.ndarray, K: np.ndarray,
                  depth_sigma_rel: float, huber: float, iterations: int, rel_tol: float = 1e-4) -> BundleResult:
    """Refine the free poses (T_cw' = exp(d) T_cw) and all points against the observations.

    Levenberg-Marquardt on the Huber (IRLS) normal equations, points eliminated by the Schur
    complement (a 6 x free-poses system). obs_depth is the measured depth of an observation or
    NaN; residuals are in units of their noise (1 px; ``depth_sigma_rel`` x depth), ``huber`` too.
    Stops after ``iterations`` or once a step lowers the cost by less than ``rel_tol`` of it.
    """
    P, Q = len(poses_cw), len(xyz)
    free = np.flatnonzero(~fixed)
    F = len(free)
    slot = -np.ones(P, np.int64)
    slot[free] = np.arange(F)
    R, t, X = poses_cw[:, :3, :3].copy(), poses_cw[:, :3, 3].copy(), xyz.copy()
    args = (obs_pose, obs_point, obs_px, obs_depth, K, depth_sigma_rel)
    e, Jp, Jl = _linearise(R, t, X, *args)
    cost0 = cost = _cost(e, huber)
    lam = 1e-3
    s_obs = slot[obs_pose]
    on = s_obs >= 0
    order = np.argsort(obs_point, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(obs_point[order]) != 0])
    pts_seen = obs_point[order][starts]

    def by_point(v: np.ndarray) -> np.ndarray:
        """Sums of per-observation rows by point (faster than np.add.at)."""
        out = np.zeros((Q, *v.shape[1:]))
        out[pts_seen] = np.add.reduceat(v[order], starts, axis=0)
        return out

    converged = False
    for _ in range(iterations):
        W = _huber_weights(e, huber)
        JlW = Jl.transpose(0, 2, 1) * W[:, None, :]          # (N,3,3) Jl^T W
        Hll = by_point(JlW @ Jl)
        gl = by_point(np.einsum("nij,nj->ni", JlW, e))
        JpW = Jp[on].transpose(0, 2, 1) * W[on][:, None, :]   # (n,6,3)
        Hpp = np.zeros((F, 6, 6))
        np.add.at(Hpp, s_obs[on], JpW @ Jp[on])
        gp = np.zeros((F, 6))
        np.add.at(gp, s_obs[on], np.einsum("nij,nj->ni", JpW, e[on]))
        Hpl4 = np.zeros((Q, F, 6, 3))                         # pose-point blocks, by point
        Hpl4[obs_point[on], s_obs[on]] = JpW @ Jl[on]         # a keyframe observes a point once
        Hpl = Hpl4.reshape(Q, 6 * F, 3)
        gp_flat = gp.reshape(-1)
        Hpp_flat = np.zeros((6 * F, 6 * F))
        for i in range(F):
            Hpp_flat[6 * i:6 * i + 6, 6 * i:6 * i + 6] = Hpp[i]
        eye3 = np.eye(3)
        while True:
            Hll_inv = np.linalg.inv(Hll + lam * (Hll * eye3) + 1e-9 * eye3)
            HplHinv = Hpl @ Hll_inv                                # (Q,6F,3)
            # sums over points by einsum, not BLAS: a multi-threaded BLAS on a busy machine made this
            # step 10-100x slower (threads spinning for a core)
            A = HplHinv.transpose(1, 0, 2).reshape(6 * F, 3 * Q)
            Bt = Hpl.transpose(1, 0, 2).reshape(6 * F, 3 * Q)
            S = Hpp_flat + lam * np.diag(np.diag(Hpp_flat)) - np.einsum("ak,bk->ab", A, Bt)
            b = -(gp_flat - np.einsum("ak,k->a", A, gl.reshape(-1)))
            dp_flat = np.linalg.solve(S + 1e-12 * np.eye(6 * F), b) if F else np.zeros(0)
            dp = dp_flat.reshape(F, 6)
            dl = -np.einsum("qij,qj->qi", Hll_inv, gl + np.einsum("qak,a->qk", Hpl, dp_flat))
            R2, t2 = R.copy(), t.copy()
            if F:
                Rd = np.stack([rotate(np.repeat(d[None, :3], 3, axis=0), np.eye(3)).T for d in dp])
                R2[free] = Rd @ R[free]
                t2[free] = np.einsum("fij,fj->fi", Rd, t[free]) + dp[:, 3:]
            X2 = X + dl
            e2, Jp2, Jl2 = _linearise(R2, t2, X2, *args)
            c2 = _cost(e2, huber)
            if c2 < cost:
                converged = cost - c2 < rel_tol * cost
                R, t, X, e, Jp, Jl, cost = R2, t2, X2, e2, Jp2, Jl2, c2
                lam = max(lam / 10, 1e-7)
                break
            lam *= 10
            if lam > 1e4:
                converged = True
                break
        if converged:
            break
    out = poses_cw.copy()
    out[:, :3, :3], out[:, :3, 3] = R, t
    return BundleResult(out, X, np.linalg.norm(e[:, :2], axis=1), cost0, cost)


def _huber(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 0.5 * r * r, k * (a - 0.5 * k))
