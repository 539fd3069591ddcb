"""The closed loop: IBVS to the hover above the site, then touch-down; batched over runs.

The controller never sees the true pose. Each control step it gets a SLAM-like estimate
(truth + white noise + random-walk drift on position and yaw, white noise on roll, pitch
and velocity; seeded) and projects the four landing-square corners through it into the
virtual camera (as the paper projects its synthetic map points with the ORB-SLAM3 pose).
Roll, pitch and body rates for the attitude loop come from the IMU (truth): a flight
controller has them. The real camera (true pose) decides whether the corners are still in
the image.

Phases per run: 0 = IBVS to the hover at ``desired_depth_m`` (q_d = (0, 0, 1)); when the
low-passed estimated feature error stays below ``switch_error_px`` for ``switch_hold_s``,
1 = touch-down: the same law with the desired depth ramped down at ``descent_speed_m_s``
through the last site estimate (the corners leave the image below ~1.3 m, so visibility is
no longer checked). A run stops on touch-down, on losing the corners during IBVS, on tilt
beyond ``abort_tilt_deg``, on ground contact before the hover, or on timeout; each with a
reason. Finished runs are frozen while the others go on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from slzcli.config import Config
from slzcli.control import dynamics as dyn
from slzcli.control import features as ft
from slzcli.control import ibvs
from slzcli.errors import ConfigError

REASONS = ("running", "touchdown", "site_not_in_view", "corners_lost", "tilt_limit", "ground_contact",
           "timeout")
_CODE = {name: i for i, name in enumerate(REASONS)}
SCENARIOS = {1: (0.0, 0.0, 10.0), 2: (-3.0, 12.0, 9.0), 3: (0.0, 0.0, 7.0), 4: (0.0, 0.0, 10.0)}
"""Paper sec. 3 start positions (m, world frame of the paper's Gazebo worlds)."""


@dataclass(frozen=True)
class Target:
    """The landing square in the world (ENU, z up): centre and the four Eq. 10 corners."""

    center_world: np.ndarray     # (3,)
    corners_world: np.ndarray    # (4, 3)


@dataclass(frozen=True, eq=False)
class SimResult:
    """Per-run outcomes (arrays of length N) and, when asked, the per-step log of every run."""

    reason: np.ndarray           # (N,) str
    success: np.ndarray          # (N,) bool
    stabilisation_time_s: np.ndarray
    settling_time_s: np.ndarray  # true error last above settling_fraction of its start value (IBVS phase)
    switch_time_s: np.ndarray
    final_feature_error_px: np.ndarray
    final_yaw_error_deg: np.ndarray
    touchdown_error_m: np.ndarray
    touchdown_speed_m_s: np.ndarray
    max_tilt_deg: np.ndarray
    landing_time_s: np.ndarray
    starts_world: np.ndarray     # (N, 4) x, y, z, yaw_deg (ENU)
    sim_time_s: float
    log: dict[str, np.ndarray] | None

    def metrics(self, i: int = 0) -> dict[str, Any]:
        """One run's metrics as plain JSON values (NaN -> None)."""
        def num(a: np.ndarray) -> float | None:
            v = float(a[i])
            return None if math.isnan(v) else round(v, 6)
        return {
            "success": bool(self.success[i]), "reason": str(self.reason[i]),
            "stabilisation_time_s": num(self.stabilisation_time_s), "settling_time_s": num(self.settling_time_s),
            "switch_time_s": num(self.switch_time_s),
            "final_feature_error_px": num(self.final_feature_error_px),
            "final_yaw_error_deg": num(self.final_yaw_error_deg),
            "touchdown_error_m": num(self.touchdown_error_m), "touchdown_speed_m_s": num(self.touchdown_speed_m_s),
            "max_tilt_deg": num(self.max_tilt_deg), "landing_time_s": num(self.landing_time_s),
            "start_world": [round(float(v), 6) for v in self.starts_world[i]],
        }


def start_from_offsets(target: Target, offsets: np.ndarray) -> np.ndarray:
    """(N, 3|4) offsets from the site centre (x, y, up m[, yaw deg]) -> absolute (N, 4) world starts."""
    off = np.atleast_2d(np.asarray(offsets, float))
    out = np.zeros((off.shape[0], 4))
    out[:, :3] = target.center_world + off[:, :3]
    if off.shape[1] > 3:
        out[:, 3] = off[:, 3]
    return out


def simulate(target: Target, starts_world: np.ndarray, config: Config, *, log: bool = False,
             seed: int | None = None) -> SimResult:
    """Fly N landings from (N, 4) world starts (x, y, z m, yaw deg; ENU) onto ``target``.

    ``seed`` overrides ``control.noise.seed`` (noise, drift, gusts). Run i's noise depends on N.
    """
    c, sim, nz = config.control, config.control.sim, config.control.noise
    ratio = sim.control_dt_s / sim.dynamics_dt_s
    n_sub = int(round(ratio))
    if n_sub < 1 or abs(ratio - n_sub) > 1e-6:
        raise ConfigError("control.sim.control_dt_s", "must be a whole multiple of control.sim.dynamics_dt_s")
    params = dyn.Params.from_config(config)
    cam = ft.CameraModel.from_config(config)
    gains = ibvs.Gains.from_config(config)
    wind = dyn.Wind.from_config(config)
    rng = np.random.default_rng(nz.seed if seed is None else seed)
    dt = sim.control_dt_s
    z_star = c.desired_depth_m
    f = cam.f

    starts = np.atleast_2d(np.asarray(starts_world, float))
    n = starts.shape[0]
    corners = dyn.enu_to_ned(target.corners_world)
    a_d = ft.desired_area(corners, f, z_star)
    r_star = math.sqrt(a_d / corners.shape[0])           # RMS corner radius at the hover, px
    px_scale = np.array([f, f, r_star])                  # feature error -> pixel-equivalent
    ground_z_ned = -float(target.center_world[2]) - config.uav.size_m[2] / 2  # body origin at contact
    qpsi_d = np.full(n, math.radians(c.yaw_feature_deg))
    sym = math.radians(c.yaw_symmetry_deg)
    att_sigma = math.radians(nz.attitude_sigma_deg)
    yaw_rw = math.radians(nz.yaw_drift_deg_sqrt_s) * math.sqrt(dt)
    pos_rw = nz.position_drift_m_sqrt_s * math.sqrt(dt)

    x = dyn.State.at_rest(dyn.enu_to_ned(starts[:, :3]), dyn.yaw_enu_to_ned(np.deg2rad(starts[:, 3]))).vector()
    e_i = np.zeros((n, 3))
    drift = np.zeros((n, 3))
    yaw_drift = np.zeros(n)
    gust = wind.initial_gust(n, rng)
    phase = np.zeros(n, int)
    code = np.zeros(n, int)
    t_switch = np.full(n, np.nan)
    last_above = np.zeros(n)
    last_above_settle = np.zeros(n)
    e_px_start = np.zeros(n)
    filt_vec = np.zeros((n, 3))
    held = np.zeros(n)
    out = {k: np.full(n, np.nan) for k in ("stab", "settle", "final_px", "final_yaw", "td_err", "td_speed", "t_end")}
    max_tilt = np.zeros(n)
    prev_att_d: np.ndarray | None = None
    torque = np.zeros((n, 3))
    rows: list[dict[str, np.ndarray]] = []
    steps = int(math.ceil(sim.timeout_s / dt))
    t = 0.0

    for k in range(steps + 1):
        t = k * dt
        running = code == 0
        if not running.any():
            break
        p, v, w = x[:, 0:3], x[:, 3:6], x[:, 10:13]
        r_ib = dyn.quat_to_rot(x[:, 6:10])
        roll, pitch, yaw = dyn.euler_from_rot(r_ib)
        rates = dyn.euler_rates(roll, pitch, w)
        tilt = dyn.tilt(r_ib)
        max_tilt = np.where(running, np.maximum(max_tilt, tilt), max_tilt)

        # Truth: real camera (visibility, pixels) and true virtual features (metrics only).
        t_ic = p + r_ib @ cam.t_BC
        r_ic = r_ib @ cam.R_BC
        pix, depth = ft.camera_pixels(corners, r_ic, t_ic, cam)
        pv_true = ft.virtual_points(corners, t_ic, yaw + cam.yaw_on_body)
        uv_true = ft.virtual_pixels(pv_true, f)
        if sim.visibility == "real":
            visible = ft.in_image(pix, depth, cam)
        else:
            visible = ft.in_image(uv_true + np.array([cam.cx, cam.cy]), pv_true[..., 2], cam)
        q_true = ft.features(uv_true, a_d, f)

        # The SLAM-like estimate the controller sees.
        drift += rng.normal(0.0, pos_rw, (n, 3))
        yaw_drift += rng.normal(0.0, yaw_rw, n)
        p_est = p + drift + rng.normal(0.0, nz.position_sigma_m, (n, 3))
        att_noise = rng.normal(0.0, att_sigma, (n, 3))
        yaw_est = yaw + yaw_drift + att_noise[:, 2]
        r_est = dyn.quat_to_rot(dyn.quat_from_euler(roll + att_noise[:, 0], pitch + att_noise[:, 1], yaw_est))
        t_ic_est = p_est + r_est @ cam.t_BC
        yaw_v = yaw_est + cam.yaw_on_body
        uv = ft.virtual_pixels(ft.virtual_points(corners, t_ic_est, yaw_v), f)
        q = ft.features(uv, a_d, f)
        q_psi = ft.yaw_feature(uv)
        # camera velocity = body velocity + w x offset (zero with the default mount)
        v_cam = v + np.einsum("nij,nj->ni", r_ib, np.cross(w, cam.t_BC))
        v_est = v_cam + rng.normal(0.0, nz.velocity_sigma_m_s, (n, 3))
        v_v = np.einsum("nji,nj->ni", dyn.rot_z(yaw_v), v_est)

        # Desired features: the hover, then the touch-down ramp of the desired depth.
        q_d = np.zeros((n, 3))
        q_d_rate = np.zeros((n, 3))
        descending = phase == 1
        q_d[:, 2] = np.where(descending, 1.0 - sim.descent_speed_m_s * (t - t_switch) / z_star, 1.0)
        q_d_rate[:, 2] = np.where(descending, -sim.descent_speed_m_s / z_star, 0.0)
        e = q - q_d
        # psi' of V is taken as the gyro z rate (equal to the Euler yaw rate when level): the exact
        # Euler rate (sin(phi) q + cos(phi) r) / cos(theta) couples pitch-rate transients into S and
        # made the cascade oscillate at the control rate.
        psi_rate = w[:, 2]
        # psi'' from the model (last yaw torque), not a finite difference: differencing the Euler
        # yaw rate feeds roll/pitch-rate transients back into S' and made the loop chatter.
        psi_acc = (torque[:, 2] - (w[:, 0] * w[:, 1] * (params.inertia[1] - params.inertia[0]))) / params.inertia[2]
        e_dot = ibvs.error_rate(q, q_d_rate, v_v, psi_rate, z_star)
        force_v, e_f = ibvs.control_force(e, e_dot, e_i, psi_rate, psi_acc, params.mass_kg, gains)
        lyap = ibvs.lyapunov(e_f, e_i, gains.K_i)
        thrust, roll_d, pitch_d, sat = ibvs.thrust_attitude(force_v, cam.yaw_on_body, params.mass_kg,
                                                            params.gravity, params.thrust_min_n,
                                                            params.thrust_max_n, gains.max_tilt_rad)
        # Anti-windup: integrate only unsaturated and near the hover (integral separation). The
        # transient's e_f = K_e e(0) would otherwise leave a slow K_i mode (~K_i/K_p = 0.02 /s) that
        # holds the error near 1 px for tens of seconds.
        e_px_est = np.linalg.norm((q - q_d) * px_scale, axis=1)
        integrate = running & ~sat & (e_px_est < c.integral_zone_px)
        e_i = e_i + np.where(integrate[:, None], e_f * dt, 0.0)
        att_d = np.stack([roll_d, pitch_d], axis=1)
        att_d_rate = (att_d - prev_att_d) / dt if prev_att_d is not None else np.zeros((n, 2))
        prev_att_d = att_d
        if k == 0 and sym > 0:   # a square looks the same every `sym`: turn to the nearest alignment
            qpsi_d = qpsi_d + sym * np.round(ft.wrap_angle(q_psi - qpsi_d) / sym)
        yaw_err = ft.wrap_angle(q_psi - qpsi_d)
        torque = ibvs.attitude_torque(roll_d - roll, att_d_rate[:, 0] - rates[:, 0], pitch_d - pitch,
                                      att_d_rate[:, 1] - rates[:, 1], yaw_err, psi_rate, gains, params.torque_max)

        # Errors in pixels: the estimate (switching) and the truth (metrics).
        e_px_true = np.linalg.norm((q_true - np.array([0.0, 0.0, 1.0])) * px_scale, axis=1)
        yaw_err_true = ft.wrap_angle(ft.yaw_feature(uv_true) - qpsi_d)
        alpha = min(1.0, dt / sim.error_filter_s) if sim.error_filter_s > 0 else 1.0
        e_vec = (q - np.array([0.0, 0.0, 1.0])) * px_scale   # low-pass the vector: noise averages out
        filt_vec = e_vec if k == 0 else filt_vec + alpha * (e_vec - filt_vec)
        filt_px = np.linalg.norm(filt_vec, axis=1)

        if log:
            row = _log_row(t, x, roll, pitch, yaw, thrust, torque, q, e, e_f, e_i, lyap, q_true, e_px_true,
                           yaw_err_true, pix, uv, phase)
            rows.append(row)

        # Stop conditions (in priority order), then the phase switch.
        ibvs_phase = running & (phase == 0)
        last_above = np.where(ibvs_phase & (e_px_true >= sim.stable_error_px), t + dt, last_above)
        if k == 0:
            e_px_start = e_px_true.copy()
        last_above_settle = np.where(ibvs_phase & (e_px_true >= sim.settling_fraction * e_px_start), t + dt,
                                     last_above_settle)
        stop = np.zeros(n, int)
        stop = np.where(running & (k == 0) & ~visible, _CODE["site_not_in_view"], stop)
        stop = np.where(running & (stop == 0) & ibvs_phase & ~visible, _CODE["corners_lost"], stop)
        stop = np.where(running & (stop == 0) & (tilt > math.radians(sim.abort_tilt_deg)), _CODE["tilt_limit"], stop)
        on_ground = p[:, 2] >= ground_z_ned
        stop = np.where(running & (stop == 0) & on_ground, np.where(descending, _CODE["touchdown"],
                                                                    _CODE["ground_contact"]), stop)
        stop = np.where(running & (stop == 0) & (k == steps), _CODE["timeout"], stop)
        ending = stop > 0
        code = np.where(ending, stop, code)
        out["t_end"] = np.where(ending, t, out["t_end"])
        landed = stop == _CODE["touchdown"]
        p_enu = dyn.ned_to_enu(p)
        out["td_err"] = np.where(landed, np.hypot(*(p_enu[:, :2] - target.center_world[:2]).T), out["td_err"])
        out["td_speed"] = np.where(landed, np.linalg.norm(v, axis=1), out["td_speed"])

        below = ibvs_phase & ~ending & (filt_px < sim.switch_error_px)
        held = np.where(below, held + dt, 0.0)
        switch = below & (held >= sim.switch_hold_s)
        if switch.any():
            phase = np.where(switch, 1, phase)
            t_switch = np.where(switch, t, t_switch)
            out["final_px"] = np.where(switch, e_px_true, out["final_px"])
            out["final_yaw"] = np.where(switch, np.degrees(np.abs(yaw_err_true)), out["final_yaw"])
            ok = e_px_true < sim.stable_error_px
            out["stab"] = np.where(switch & ok, last_above, out["stab"])
            out["settle"] = np.where(switch, last_above_settle, out["settle"])
        if not (code == 0).any():
            break

        # Integrate the rigid body over one control period (inputs held), finished runs frozen.
        x_new = x.copy()
        if sim.attitude == "ideal":   # roll/pitch follow the command at once; yaw stays dynamic
            x_new[:, 6:10] = dyn.quat_from_euler(roll_d, pitch_d, yaw)
            x_new[:, 10:12] = 0.0
            torque = torque.copy()
            torque[:, :2] = 0.0
        for _ in range(n_sub):
            force_d = wind.force(x_new[:, 3:6], gust)
            x_new = dyn.rk4_step(x_new, sim.dynamics_dt_s, thrust, torque, force_d, params)
        gust = wind.next_gust(gust, dt, rng)
        x = np.where((code == 0)[:, None], x_new, x)

    reason = np.array([REASONS[i] for i in code])
    within = out["td_err"] <= sim.success_radius_m
    return SimResult(reason, (reason == "touchdown") & within, out["stab"], out["settle"], t_switch, out["final_px"],
                     out["final_yaw"], out["td_err"], out["td_speed"], np.degrees(max_tilt), out["t_end"],
                     starts, t, _stack(rows) if log else None)


def _log_row(t: float, x: np.ndarray, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, thrust: np.ndarray,
             torque: np.ndarray, q: np.ndarray, e: np.ndarray, e_f: np.ndarray, e_i: np.ndarray, lyap: np.ndarray,
             q_true: np.ndarray, e_px_true: np.ndarray, yaw_err: np.ndarray, pix: np.ndarray, uv: np.ndarray,
             phase: np.ndarray) -> dict[str, np.ndarray]:
    return {"t": np.full(x.shape[0], t), "p_world": dyn.ned_to_enu(x[:, 0:3]), "v_world": dyn.ned_to_enu(x[:, 3:6]),
            "euler_ned": np.stack([roll, pitch, yaw], axis=1), "w_body": x[:, 10:13].copy(), "thrust": thrust,
            "torque": torque, "q": q, "e_q": e, "e_f": e_f, "e_i": e_i.copy(), "lyapunov": lyap, "q_true": q_true,
            "e_px_true": e_px_true, "yaw_err_true": yaw_err, "corner_px": pix, "virtual_uv": uv, "phase": phase.copy()}


def _stack(rows: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """List of per-step dicts of (N, ...) -> dict of (steps, N, ...) arrays."""
    if not rows:
        return {}
    return {k: np.stack([r[k] for r in rows]) for k in rows[0]}


def sample_starts(base_world: np.ndarray, runs: int, config: Config, seed: int) -> np.ndarray:
    """Monte Carlo starts: uniform disc around base (x, y), uniform +-dz, +-yaw (config montecarlo)."""
    mc = config.control.montecarlo
    rng = np.random.default_rng(seed)
    radius = mc.start_radius_m * np.sqrt(rng.uniform(0, 1, runs))
    ang = rng.uniform(0, 2 * np.pi, runs)
    out = np.repeat(np.asarray(base_world, float)[None, :4], runs, axis=0)
    out[:, 0] += radius * np.cos(ang)
    out[:, 1] += radius * np.sin(ang)
    out[:, 2] += rng.uniform(-mc.start_dz_m, mc.start_dz_m, runs)
    out[:, 3] += rng.uniform(-mc.start_yaw_deg, mc.start_yaw_deg, runs)
    return out


def resolve_start(target: Target, config: Config, scenario: int | None = None,
                  start: tuple[float, ...] | None = None) -> np.ndarray:
    """The (4,) world start (x, y, z m, yaw deg; ENU) a user asked for.

    ``--scenario N``: the paper's start position, absolute in the run's world frame (the paper's
    scenario starts are world positions; its site for scenario 1 was at (3.24, 3.32, 0.4)).
    ``--start x,y,z[,yaw]``: an offset from the site centre (world x, y, up; yaw in degrees),
    because a run's world frame (first camera, odometry) is arbitrary. Neither: the configured
    offset ``control.sim.start_m`` (10 m above the site).
    """
    if scenario is not None:
        if scenario not in SCENARIOS:
            raise ConfigError("--scenario", f"must be one of {sorted(SCENARIOS)}, got {scenario}")
        return np.array([*SCENARIOS[scenario], 0.0])
    offset = start if start is not None else config.control.sim.start_m
    if len(offset) not in (3, 4):
        raise ConfigError("--start", f"expected x,y,z[,yaw], got {len(offset)} values")
    return start_from_offsets(target, np.array(offset, float))[0]
