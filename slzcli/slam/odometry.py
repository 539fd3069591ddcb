"""Built-in RGB-D visual odometry (permissive licence): ORB features, a local map, PnP-RANSAC.

Per frame: ORB features; matches against the points of the last few keyframes (ratio test,
then kept only near their projection through a constant-velocity prediction); PnP with RANSAC
gives the pose. A keyframe (motion or tracked-ratio rule) adds map points: from depth where
the sensor has it, else by triangulating with the previous keyframe (points beyond the depth
range). When tracking fails the frame is reported LOST, relocalisation is tried against every
keyframe's points, and after ``reinit_after_frames`` failures a new map is started at the
last known pose (the world frame may then be off by the motion while lost).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from slzcli.errors import SlzError
from slzcli.geometry import invert_pose, project, transform_points
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.bundle import bundle_adjust
from slzcli.slam.features import detect, make_orb, ratio_matches
from slzcli.slam.keyframes import is_new_keyframe
from slzcli.types import Frame

if TYPE_CHECKING:
    from slzcli.config import SlamCfg

log = logging.getLogger(__name__)


@dataclass
class _KF:
    pose: np.ndarray
    point_ids: np.ndarray        # map points this keyframe observes
    pixels: np.ndarray           # (N,2) where it observes them
    depth: np.ndarray            # (N,) measured depth there (m), NaN where out of range
    free_pixels: np.ndarray      # keypoints without depth and without a map point (for triangulation)
    free_desc: np.ndarray
    tracked: int


class OdometryBackend(BackendBase):
    name = "odometry"

    def __init__(self, slam: SlamCfg) -> None:
        self.cfg = slam.odometry
        self.kf_cfg = slam.keyframe
        o = slam.orb
        self.orb = make_orb(o.n_features, o.n_levels, o.scale_factor, o.fast_threshold)
        self.xyz = np.zeros((0, 3))
        self.desc = np.zeros((0, 32), np.uint8)
        self.kfs: list[_KF] = []
        self.last_pose: np.ndarray | None = None
        self.velocity = np.eye(4)   # T_prev_curr of the last tracked step
        self.lost_for = 0
        self.segment = 0
        self._keyframe: MapPoints | None = None

    # ------------------------------------------------------------------ helpers
    def _backproject(self, frame: Frame, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points of pixels with a usable depth, and that mask."""
        h, w = frame.shape
        ui = np.clip(np.round(px[:, 0]).astype(int), 0, w - 1)
        vi = np.clip(np.round(px[:, 1]).astype(int), 0, h - 1)
        z = frame.depth_m[vi, ui].astype(np.float64)
        ok = np.isfinite(z) & (z >= self.cfg.min_depth_m) & (z <= self.cfg.max_depth_m)
        K = frame.K
        pc = np.stack([(px[:, 0] - K[0, 2]) * z / K[0, 0], (px[:, 1] - K[1, 2]) * z / K[1, 1], z], axis=1)
        return pc, ok

    def _match(self, desc: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ratio-test matches of frame descriptors to map points ``ids``: (frame idx, map id)."""
        q, j = ratio_matches(desc, self.desc[ids], self.cfg.ratio_test)
        t = ids[j]
        # one frame feature per map point: keep the first
        _, first = np.unique(t, return_index=True)
        return q[first], t[first]

    def _pnp(self, frame: Frame, px: np.ndarray, q: np.ndarray, ids: np.ndarray,
             guess: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray]:
        if len(q) < self.cfg.min_inliers:
            return None, np.zeros(0, int)
        obj, img, cfg = self.xyz[ids].astype(np.float64), px[q].astype(np.float64), self.cfg
        if guess is None:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(
                obj, img, frame.K, None, iterationsCount=cfg.pnp_iterations, reprojectionError=cfg.pnp_reprojection_px,
                confidence=cfg.pnp_confidence, flags=cv2.SOLVEPNP_EPNP)
        else:
            T_cw = invert_pose(guess)
            rvec, _ = cv2.Rodrigues(T_cw[:3, :3])
            ok, rvec, tvec, inl = cv2.solvePnPRansac(
                obj, img, frame.K, None, rvec=rvec.copy(), tvec=T_cw[:3, 3].reshape(3, 1).copy(),
                useExtrinsicGuess=True, iterationsCount=cfg.pnp_iterations,
                reprojectionError=cfg.pnp_reprojection_px, confidence=cfg.pnp_confidence, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inl is None or len(inl) < self.cfg.min_inliers:
            return None, np.zeros(0, int)
        inl = inl[:, 0]
        rvec, tvec = cv2.solvePnPRefineLM(self.xyz[ids[inl]], px[q[inl]].astype(np.float64), frame.K, None, rvec, tvec)
        R, _ = cv2.Rodrigues(rvec)
        T_cw = np.eye(4)
        T_cw[:3, :3], T_cw[:3, 3] = R, tvec[:, 0]
        return invert_pose(T_cw), inl

    def _add_points(self, xyz: np.ndarray, desc: np.ndarray) -> np.ndarray:
        ids = np.arange(len(self.xyz), len(self.xyz) + len(xyz))
        self.xyz = np.concatenate([self.xyz, xyz])
        self.desc = np.concatenate([self.desc, desc])
        return ids

    def _triangulate(self, frame: Frame, pose: np.ndarray, px: np.ndarray, desc: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Map points for depth-less features matched with the previous keyframe's depth-less ones:
        (xyz, index into px, descriptors, index into the previous keyframe's free pixels)."""
        empty = (np.zeros((0, 3)), np.zeros(0, int), np.zeros((0, 32), np.uint8), np.zeros(0, int))
        if not self.kfs or len(px) < 2 or len(self.kfs[-1].free_desc) < 2:
            return empty
        prev = self.kfs[-1]
        pairs = np.stack(ratio_matches(desc, prev.free_desc, self.cfg.ratio_test), axis=1)
        if len(pairs) == 0:
            return empty
        K = frame.K
        P1 = K @ invert_pose(prev.pose)[:3]
        P2 = K @ invert_pose(pose)[:3]
        a, b = prev.free_pixels[pairs[:, 1]], px[pairs[:, 0]]
        Xh = cv2.triangulatePoints(P1, P2, a.T.astype(np.float64), b.T.astype(np.float64))
        X = (Xh[:3] / Xh[3]).T
        r1 = X - prev.pose[:3, 3]
        r2 = X - pose[:3, 3]
        cosang = np.sum(r1 * r2, 1) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
        parallax_ok = cosang < np.cos(np.radians(self.cfg.min_parallax_deg))
        uv1, in1 = project(X, prev.pose, K, (frame.intrinsics.height, frame.intrinsics.width))
        uv2, in2 = project(X, pose, K, (frame.intrinsics.height, frame.intrinsics.width))
        err = np.maximum(np.linalg.norm(uv1 - a, axis=1), np.linalg.norm(uv2 - b, axis=1))
        ok = parallax_ok & in1 & in2 & (err < self.cfg.max_triangulation_error_px)
        return X[ok], pairs[ok, 0], desc[pairs[ok, 0]], pairs[ok, 1]

    def _make_keyframe(self, frame: Frame, pose: np.ndarray, px: np.ndarray, desc: np.ndarray,
                       matched_q: np.ndarray, matched_ids: np.ndarray) -> None:
        pc, has_depth = self._backproject(frame, px)
        z = np.where(has_depth, pc[:, 2], np.nan)
        new = np.ones(len(px), bool)
        new[matched_q] = False
        pw = transform_points(pose, pc)
        d_idx = np.flatnonzero(new & has_depth)
        d_ids = self._add_points(pw[d_idx], desc[d_idx])
        free = np.flatnonzero(new & ~has_depth)
        tri_xyz, tri_local, tri_desc, tri_prev = self._triangulate(frame, pose, px[free], desc[free])
        t_ids = self._add_points(tri_xyz, tri_desc)
        if len(t_ids):  # the previous keyframe observes the triangulated points too (for the bundle adjustment)
            prev = self.kfs[-1]
            prev.point_ids = np.concatenate([prev.point_ids, t_ids])
            prev.pixels = np.concatenate([prev.pixels, prev.free_pixels[tri_prev]])
            prev.depth = np.concatenate([prev.depth, np.full(len(t_ids), np.nan)])
        still_free = np.setdiff1d(np.arange(len(free)), tri_local)
        ids = np.concatenate([matched_ids, d_ids, t_ids]).astype(np.int64)
        pix = np.concatenate([px[matched_q], px[d_idx], px[free][tri_local]]).reshape(-1, 2).astype(np.float64)
        dep = np.concatenate([z[matched_q], z[d_idx], np.full(len(t_ids), np.nan)])
        self.kfs.append(_KF(pose, ids, pix, dep, px[free][still_free], desc[free][still_free],
                            len(matched_ids) + len(d_ids)))
        if self.cfg.ba_keyframes > 0 and len(self.kfs) > 1:
            self._local_bundle_adjust(frame.K)
        kf = self.kfs[-1]
        self._keyframe = MapPoints(kf.point_ids, self.xyz[kf.point_ids].copy(), kf.pixels.copy(), len(self.kfs) - 1,
                                   frame.stamp_ns, kf.pose.copy())

    def _local_bundle_adjust(self, K: np.ndarray) -> None:
        """Refine the last ``ba_keyframes`` keyframe poses and the points they see (bundle.py).

        The keyframe before them is held fixed (it fixes the gauge with the depth terms); points seen
        once and without depth are left out (nothing constrains them). Observations left with a large
        reprojection error are dropped from their keyframe (mismatches, points across a depth edge).
        """
        n_free = min(self.cfg.ba_keyframes, len(self.kfs) - 1)
        win = self.kfs[-(n_free + 1):]
        kf_of = np.concatenate([np.full(len(k.point_ids), i) for i, k in enumerate(win)])
        pid = np.concatenate([k.point_ids for k in win])
        px = np.concatenate([k.pixels for k in win])
        dep = np.concatenate([k.depth for k in win])
        uniq, inv, count = np.unique(pid, return_inverse=True, return_counts=True)
        depth_seen = np.zeros(len(uniq), bool)
        depth_seen[inv[np.isfinite(dep)]] = True
        keep = (count >= 2) | depth_seen
        use = keep[inv]
        local = -np.ones(len(uniq), np.int64)
        local[keep] = np.arange(int(keep.sum()))
        if use.sum() < self.cfg.min_inliers:
            return
        poses_cw = np.stack([invert_pose(k.pose) for k in win])
        fixed = np.zeros(len(win), bool)
        fixed[0] = True
        res = bundle_adjust(poses_cw, fixed, self.xyz[uniq[keep]], kf_of[use], local[inv[use]], px[use], dep[use], K,
                            self.cfg.ba_depth_sigma_rel, self.cfg.ba_huber, self.cfg.ba_iterations)
        self.xyz[uniq[keep]] = res.xyz
        for k, T_cw in zip(win[1:], res.poses_cw[1:], strict=True):
            k.pose = invert_pose(T_cw)
        bad = np.zeros(len(pid), bool)
        bad[np.flatnonzero(use)] = res.reproj_px > self.cfg.ba_outlier_px
        start = 0
        for k in win:
            n = len(k.point_ids)
            b = bad[start:start + n]
            start += n
            if b.any():
                k.point_ids, k.pixels, k.depth = k.point_ids[~b], k.pixels[~b], k.depth[~b]
        self.last_pose = win[-1].pose

    # ------------------------------------------------------------------ protocol
    def track(self, frame: Frame) -> TrackResult:
        self._keyframe = None
        try:
            px, desc = detect(self.orb, frame.rgb)
        except cv2.error as err:  # e.g. an image smaller than the ORB pyramid's border
            h, w = frame.rgb.shape[:2]
            raise SlzError(f"{frame.source or 'recording'}: ORB features cannot be found in frame {frame.index} "
                           f"({w}x{h} px): {' '.join(str(err).split())}") from err
        if not self.kfs:
            return self._initialise(frame, px, desc, np.eye(4))
        # the motion prior is only trusted right after a tracked frame
        guess = None if self.last_pose is None or self.lost_for else self.last_pose @ self.velocity
        pose, q, ids, inl = None, np.zeros(0, int), np.zeros(0, int), np.zeros(0, int)
        if guess is not None:
            local = np.unique(np.concatenate([k.point_ids for k in self.kfs[-self.cfg.local_keyframes:]]))
            q, ids = self._match(desc, local)
            uv, vis = project(self.xyz[ids], guess, frame.K, (frame.intrinsics.height, frame.intrinsics.width))
            near = vis & (np.linalg.norm(uv - px[q], axis=1) < self.cfg.search_radius_px)
            q, ids = q[near], ids[near]
            pose, inl = self._pnp(frame, px, q, ids, guess)
        if pose is None:  # relocalise against every keyframe's points, no motion prior
            all_ids = np.unique(np.concatenate([k.point_ids for k in self.kfs]))
            q, ids = self._match(desc, all_ids)
            pose, inl = self._pnp(frame, px, q, ids, None)
            if pose is not None:
                log.info("odometry: relocalised frame %d after %d lost frames", frame.index, self.lost_for)
        if pose is None:
            self.lost_for += 1
            if self.lost_for >= self.cfg.reinit_after_frames and self.last_pose is not None:
                res = self._initialise(frame, px, desc, self.last_pose)
                if res.state is TrackingState.OK:
                    log.info("odometry: new map at frame %d from the last known pose", frame.index)
                    return res
            self.velocity = np.eye(4)
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.LOST, None, False, 0, self.segment)
        self.velocity = invert_pose(self.last_pose) @ pose if guess is not None and self.last_pose is not None \
            else np.eye(4)
        self.lost_for = 0
        self.last_pose = pose
        mq, mids = q[inl], ids[inl]
        last = self.kfs[-1]
        if is_new_keyframe(last.pose, pose, len(mq), last.tracked, self.kf_cfg.min_translation_m,
                           self.kf_cfg.min_rotation_deg, self.kf_cfg.min_tracked_ratio):
            self._make_keyframe(frame, pose, px, desc, mq, mids)
            pose = self.kfs[-1].pose  # refined by the local bundle adjustment
        return TrackResult(frame.index, frame.stamp_ns, TrackingState.OK, pose, self._keyframe is not None, len(mq),
                           self.segment)

    def _initialise(self, frame: Frame, px: np.ndarray, desc: np.ndarray, pose: np.ndarray) -> TrackResult:
        """Start a map from this frame's depth (needs min_inliers features with depth)."""
        _, has_depth = self._backproject(frame, px)
        if has_depth.sum() < self.cfg.min_inliers:
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.INITIALISING if not self.kfs
                               else TrackingState.LOST, None, False, 0, self.segment)
        if self.kfs:
            self.segment += 1
        self.kfs = []
        self._make_keyframe(frame, pose, px, desc, np.zeros(0, int), np.zeros(0, np.int64))
        self.last_pose, self.velocity, self.lost_for = pose, np.eye(4), 0
        return TrackResult(frame.index, frame.stamp_ns, TrackingState.OK, pose.copy(), True, int(has_depth.sum()),
                           self.segment)

    def keyframe(self) -> MapPoints | None:
        return self._keyframe
