"""The closed loop: IBVS to the hover above the site, then touch-down; batched over runs.

The controller never sees the true pose. Each control step it gets a SLAM-like estimate
(truth + white noise + random-walk drift on position and yaw, white noise on roll, pitch
and velocity; seeded per run, see ``noise.py``) and projects the four landing-square
corners through it into the virtual camera (as the paper projects its synthetic map points
with the ORB-SLAM3 pose).
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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slzcli import bounds
from slzcli.config import Config, MonteCarloCfg, SimCfg, UavCfg
from slzcli.control import dynamics as dyn
from slzcli.control import features as ft
from slzcli.control import ibvs
from slzcli.control.noise import START_STREAM, FlightNoise, run_generator
from slzcli.errors import ConfigError, DatasetError
from slzcli.landing.corners import corners_problem
from slzcli.types import SimResult as SimResult  # shared with outputs/ibvs*.py
from slzcli.types import Target as Target

REASONS = ("running", "touchdown", "site_not_in_view", "corners_lost", "tilt_limit", "ground_contact",
           "timeout", "outside_radius")
"""Why a run ended. ``outside_radius``: touched down farther than ``success_radius_m`` from the site centre."""
_CODE = {name: i for i, name in enumerate(REASONS)}
SCENARIOS = {1: (0.0, 0.0, 10.0), 2: (-3.0, 12.0, 9.0), 3: (0.0, 0.0, 7.0), 4: (0.0, 0.0, 10.0)}
"""Paper sec. 3 start positions (m, world frame of the paper's Gazebo worlds)."""


def check_target(source: Path, target: Target, footprint_m: tuple[float, ...], tolerance: float) -> Target:
    """``target`` when its corners are the Eq. 10 square of ``footprint_m`` within ``tolerance``
    (``control.sim.target_tolerance``, a fraction of the footprint); else DatasetError naming ``source``."""
    problem = corners_problem(target.center_world, target.corners_world, footprint_m, tolerance)
    if problem is not None:
        raise DatasetError(source, f"site.corners_world: {problem}, beyond control.sim.target_tolerance = "
                                   f"{tolerance:g} x the side; not a landing square of this UAV: use the config "
                                   "slz detect used")
    return target


def start_from_offsets(target: Target, offsets: np.ndarray) -> np.ndarray:
    """(N, 3|4) offsets from the site centre (x, y, up m[, yaw deg]) -> absolute (N, 4) world starts."""
    off = np.atleast_2d(np.asarray(offsets, float))
    out = np.zeros((off.shape[0], 4))
    out[:, :3] = target.center_world + off[:, :3]
    if off.shape[1] > 3:
        out[:, 3] = off[:, 3]
    return out


NOISE_COLUMNS = {"drift": slice(0, 3), "yaw_drift": slice(3, 4), "position": slice(4, 7), "attitude": slice(7, 10),
                 "velocity": slice(10, 13), "gust": slice(13, 15)}
"""Columns of one control step's standard normals (``noise.FlightNoise`` rows) and what each drives."""
NOISE_WIDTH = 15
IBVS, DESCENT, APPROACH = 0, 1, 2
PHASES = ("ibvs", "descent", "approach")
"""Phase codes of the log's ``phase`` column (trajectory.csv) and their names."""
_HOVER_Q = np.array([0.0, 0.0, 1.0])  # q_d at the hover (paper: q_d = (0, 0, 1))
METRIC_KEYS = ("stab", "settle", "final_px", "final_yaw", "td_err", "td_speed", "t_end")


@dataclass(frozen=True, eq=False)
class _Setup:
    """What stays fixed during a batch: models, gains, the target's corners and scales, noise sizes."""

    config: Config
    params: dyn.Params
    cam: ft.CameraModel
    gains: ibvs.Gains
    wind: dyn.Wind
    center_world: np.ndarray
    center_ned: np.ndarray
    corners: np.ndarray          # (4, 3) NED
    a_d: float                   # desired feature area at the hover
    px_scale: np.ndarray         # feature error -> pixel-equivalent
    ground_z_ned: float          # body origin height (NED z) at ground contact
    dt: float
    n_sub: int
    steps: int
    alpha: float                 # low-pass gain of the switching error per step
    pos_rw: float                # m per step, position drift
    yaw_rw: float                # rad per step, yaw drift
    att_sigma: float             # rad
    margin_px: np.ndarray        # (2,) hand-over margin inside the image edges (u, v), px

    @property
    def sim(self) -> SimCfg:
        return self.config.control.sim


@dataclass(frozen=True, eq=False)
class _Truth:
    """The vehicle as it is: IMU attitude and rates, the real camera's view, the true virtual features."""

    p: np.ndarray
    v: np.ndarray
    w: np.ndarray
    r_ib: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    rates: np.ndarray
    tilt: np.ndarray
    pix: np.ndarray
    visible: np.ndarray
    in_margin: np.ndarray        # visible with control.approach.view_margin to spare (hand-over to IBVS)
    uv_true: np.ndarray
    q_true: np.ndarray


@dataclass(frozen=True, eq=False)
class _Estimate:
    """What the controller sees through the SLAM-like pose: features, yaw feature, velocity in V."""

    uv: np.ndarray
    q: np.ndarray
    q_psi: np.ndarray
    v_v: np.ndarray
    p: np.ndarray                # estimated position (NED)
    v: np.ndarray                # estimated camera velocity (NED)
    yaw_v: np.ndarray            # estimated yaw of the virtual camera
    drift: np.ndarray            # random-walk states after this step
    yaw_drift: np.ndarray


@dataclass(frozen=True, eq=False)
class _Command:
    """The control law's output for one step, with the intermediate terms the log keeps."""

    thrust: np.ndarray
    torque: np.ndarray
    roll_d: np.ndarray
    pitch_d: np.ndarray
    e: np.ndarray
    e_f: np.ndarray
    e_i: np.ndarray              # integral after this step
    lyap: np.ndarray
    att_d: np.ndarray
    qpsi_d: np.ndarray           # desired yaw feature (aligned to the square at step 0)


Plant = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""Another simulator's vehicle: (state (N, 13) NED/FRD as in ``dynamics``, thrust (N,) N, body torque
(N, 3) N m, held for one control period) -> the state after it. It brings its own drag and wind
(``control.wind`` is not applied)."""


def simulate(target: Target, starts_world: np.ndarray, config: Config, *, log: bool = False,
             seed: int | None = None, first_run: int = 0, plant: Plant | None = None) -> SimResult:
    """Fly N landings from (N, 4) world starts (x, y, z m, yaw deg; ENU) onto ``target``.

    ``seed`` overrides ``control.noise.seed`` (noise, drift, gusts). Row i is run ``first_run + i``:
    its noise depends only on (seed, first_run + i), not on N, so batches can be split or resized.
    ``plant``: fly the same controller in another simulator's vehicle instead of ``dynamics``
    (the independent check, ``control/rotorpy_check.py``); needs ``control.sim.attitude: dynamic``.
    """
    if plant is not None and config.control.sim.attitude != "dynamic":
        raise ConfigError("control.sim.attitude", "an external plant needs 'dynamic' (it flies the torques)")
    s = _setup(target, config)
    starts = np.atleast_2d(np.asarray(starts_world, float))
    n = starts.shape[0]
    noise = FlightNoise(config.control.noise.seed if seed is None else seed, n, NOISE_WIDTH, first_run)
    approach_on = config.control.approach.enabled

    x = dyn.State.at_rest(dyn.enu_to_ned(starts[:, :3]), dyn.yaw_enu_to_ned(np.deg2rad(starts[:, 3]))).vector()
    e_i = np.zeros((n, 3))
    drift = np.zeros((n, 3))
    yaw_drift = np.zeros(n)
    gust = s.wind.initial_gust(noise.next()[:, NOISE_COLUMNS["gust"]])
    phase = np.zeros(n, int)
    code = np.zeros(n, int)
    t_switch = np.full(n, np.nan)
    t_handover = np.full(n, np.nan)
    last_above = np.zeros(n)
    last_above_settle = np.zeros(n)
    e_px_start = np.zeros(n)
    filt_vec = np.zeros((n, 3))
    held = np.zeros(n)
    out = {k: np.full(n, np.nan) for k in METRIC_KEYS}
    max_tilt = np.zeros(n)
    phase_time = np.zeros((n, len(PHASES)))
    recoveries = np.zeros(n, int)
    goal_z = np.zeros(n)                 # approach altitude (NED z) of each run
    obs = _Observer(np.zeros((n, 3)), np.zeros((n, 3)))
    qpsi_d = np.full(n, math.radians(config.control.yaw_feature_deg))
    prev_att_d: np.ndarray | None = None
    torque = np.zeros((n, 3))
    rows: list[dict[str, np.ndarray]] = []
    t = 0.0

    for k in range(s.steps + 1):
        t = k * s.dt
        running = code == 0
        if not running.any():
            break
        z = noise.next()
        tr = _truth(x, s)
        max_tilt = np.where(running, np.maximum(max_tilt, tr.tilt), max_tilt)
        est = _estimate(tr, drift, yaw_drift, z, s)
        drift, yaw_drift = est.drift, est.yaw_drift

        # Approach <-> IBVS: out of view (with the margin) at the start or lost on the way -> approach;
        # back in view with the margin -> IBVS from a fresh start (integral, switch filter, hold).
        if approach_on:
            lost = running & ((phase == IBVS) & ~tr.visible if k else ~tr.in_margin)
            found = running & (phase == APPROACH) & tr.in_margin
            recoveries += (lost & (k > 0)).astype(int)
            goal_z = np.where(lost, np.minimum(tr.p[:, 2], s.ground_z_ned + s.config.uav.size_m[2] / 2
                                               - s.config.control.approach.min_height_m), goal_z)
            phase = np.where(lost, APPROACH, np.where(found, IBVS, phase))
        else:
            lost = found = np.zeros(n, bool)
        enter_ibvs = running & (phase == IBVS) & ((k == 0) | found)
        first_entry = enter_ibvs & np.isnan(t_handover)
        t_handover = np.where(first_entry, t, t_handover)
        e_i = np.where((lost | found)[:, None], 0.0, e_i)
        held = np.where(found, 0.0, held)
        if k == 0:
            obs = _Observer(est.v.copy(), np.zeros((n, 3)))
        obs = obs.correct(est.v, s)

        q_d, q_d_rate = _desired_features(phase, t, t_switch, s)
        cmd = _command(tr, est, q_d, q_d_rate, e_i, prev_att_d, torque, qpsi_d, running, k == 0, phase, goal_z,
                       obs.d_hat, s)
        e_i, prev_att_d, torque, qpsi_d = cmd.e_i, cmd.att_d, cmd.torque, cmd.qpsi_d

        # Errors in pixels: the estimate (switching, low-passed) and the truth (metrics).
        e_px_true = np.linalg.norm((tr.q_true - _HOVER_Q) * s.px_scale, axis=1)
        yaw_err_true = ft.wrap_angle(ft.yaw_feature(tr.uv_true) - qpsi_d)
        filt_vec = _filter_error(filt_vec, est.q, enter_ibvs, s)
        if log:
            rows.append(_log_row(t, x, tr.roll, tr.pitch, tr.yaw, cmd.thrust, torque, est.q, cmd.e, cmd.e_f, e_i,
                                 cmd.lyap, tr.q_true, e_px_true, yaw_err_true, tr.pix, est.uv, phase, obs.d_hat))

        ibvs_phase = running & (phase == IBVS)
        e_px_start = np.where(first_entry, e_px_true, e_px_start)
        last_above, last_above_settle = _last_above(last_above, last_above_settle, ibvs_phase, e_px_true,
                                                    e_px_start, t, s)
        stop = _stop_codes(k, running, ibvs_phase, phase == DESCENT, tr, approach_on, s)
        ending = stop > 0
        code = np.where(ending, stop, code)
        out = _record_end(out, stop, t, tr, s)

        switch, held = _switch_due(ibvs_phase, ending, np.linalg.norm(filt_vec, axis=1), held, s)
        if switch.any():
            phase = np.where(switch, DESCENT, phase)
            t_switch = np.where(switch, t, t_switch)
            out = _record_switch(out, switch, e_px_true, yaw_err_true, last_above, last_above_settle, s)
        if not (code == 0).any():
            break
        live = code == 0
        phase_time[live, phase[live]] += s.dt

        obs = obs.predict(cmd.thrust, tr.r_ib, s)
        if plant is None:
            x_new, torque = _integrate(x, cmd, torque, tr.yaw, gust, s)
        else:
            x_new = plant(x, cmd.thrust, torque)
        gust = s.wind.next_gust(gust, s.dt, z[:, NOISE_COLUMNS["gust"]])
        x = np.where((code == 0)[:, None], x_new, x)

    landed = code == _CODE["touchdown"]
    within = out["td_err"] <= s.sim.success_radius_m
    code = np.where(landed & ~within, _CODE["outside_radius"], code)
    reason = np.array([REASONS[i] for i in code])
    return SimResult(reason, landed & within, out["stab"], out["settle"], t_switch, out["final_px"],
                     out["final_yaw"], out["td_err"], out["td_speed"], np.degrees(max_tilt), out["t_end"],
                     starts, t, _stack(rows) if log else None, handover_time_s=t_handover,
                     approach_time_s=phase_time[:, APPROACH], ibvs_time_s=phase_time[:, IBVS],
                     descent_time_s=phase_time[:, DESCENT], recoveries=recoveries)


@dataclass(frozen=True, eq=False)
class _Observer:
    """Disturbance observer on the translational dynamics (``control.disturbance``), NED.

    ``m v' = F_model + d`` with ``F_model = -T b3 + m g e3`` (commanded thrust along the IMU attitude):
    a second-order observer ``v_hat' = (F_model + d_hat) / m + l1 (v - v_hat)``, ``d_hat' = l2 (v - v_hat)``
    with both poles at ``bandwidth_rad_s`` (l1 = 2 w, l2 = m w^2) estimates d (gusts, drag) from the
    SLAM velocity without differentiating it. Off: d_hat stays zero.
    """

    v_hat: np.ndarray
    d_hat: np.ndarray

    def correct(self, v_meas: np.ndarray, s: _Setup) -> _Observer:
        dist = s.config.control.disturbance
        if not dist.observer:
            return self
        w = dist.bandwidth_rad_s
        innov = v_meas - self.v_hat
        return _Observer(self.v_hat + s.dt * 2 * w * innov, self.d_hat + s.dt * s.params.mass_kg * w * w * innov)

    def predict(self, thrust: np.ndarray, r_ib: np.ndarray, s: _Setup) -> _Observer:
        if not s.config.control.disturbance.observer:
            return self
        m = s.params.mass_kg
        force = -thrust[:, None] * r_ib[:, :, 2] + self.d_hat
        force[:, 2] += m * s.params.gravity
        return _Observer(self.v_hat + s.dt * force / m, self.d_hat)


def _setup(target: Target, config: Config) -> _Setup:
    """Models and constants of a batch; checks that the control period is whole dynamics steps."""
    c, sim, nz = config.control, config.control.sim, config.control.noise
    ratio = sim.control_dt_s / sim.dynamics_dt_s
    n_sub = round(ratio)
    if n_sub < 1 or abs(ratio - n_sub) > 1e-6:
        raise ConfigError("control.sim.control_dt_s", "must be a whole multiple of control.sim.dynamics_dt_s")
    bounds.check(bounds.simulation_sizes(config, 1))   # before the step loop and its log
    cam = ft.CameraModel.from_config(config.camera, config.uav)
    corners = dyn.enu_to_ned(target.corners_world)
    a_d = ft.desired_area(corners, cam.f, c.desired_depth_m)
    r_star = math.sqrt(a_d / corners.shape[0])           # RMS corner radius at the hover, px
    dt = sim.control_dt_s
    return _Setup(
        config=config, params=dyn.Params.from_config(c, config.uav), cam=cam, gains=ibvs.Gains.from_config(c),
        wind=dyn.Wind.from_config(c), center_world=np.asarray(target.center_world, float),
        center_ned=dyn.enu_to_ned(np.asarray(target.center_world, float)), corners=corners,
        a_d=a_d, px_scale=np.array([cam.f, cam.f, r_star]),
        ground_z_ned=-float(target.center_world[2]) - config.uav.size_m[2] / 2,
        dt=dt, n_sub=n_sub, steps=math.ceil(sim.timeout_s / dt),
        alpha=min(1.0, dt / sim.error_filter_s) if sim.error_filter_s > 0 else 1.0,
        pos_rw=nz.position_drift_m_sqrt_s * math.sqrt(dt), yaw_rw=math.radians(nz.yaw_drift_deg_sqrt_s) * math.sqrt(dt),
        att_sigma=math.radians(nz.attitude_sigma_deg),
        margin_px=c.approach.view_margin * np.array([cam.width, cam.height], float))


def _truth(x: np.ndarray, s: _Setup) -> _Truth:
    """True attitude and rates (the IMU), the real camera's corner pixels and visibility, true features."""
    cam = s.cam
    p, v, w = x[:, 0:3], x[:, 3:6], x[:, 10:13]
    r_ib = dyn.quat_to_rot(x[:, 6:10])
    roll, pitch, yaw = dyn.euler_from_rot(r_ib)
    t_ic = p + r_ib @ cam.t_BC
    pix, depth = ft.camera_pixels(s.corners, r_ib @ cam.R_BC, t_ic, cam)
    pv_true = ft.virtual_points(s.corners, t_ic, yaw + cam.yaw_on_body)
    uv_true = ft.virtual_pixels(pv_true, cam.f)
    if s.sim.visibility == "real":
        seen, seen_depth = pix, depth
    else:
        seen, seen_depth = uv_true + np.array([cam.cx, cam.cy]), pv_true[..., 2]
    visible = ft.in_image(seen, seen_depth, cam)
    in_margin = ft.in_image(seen, seen_depth, cam, s.margin_px)
    return _Truth(p, v, w, r_ib, roll, pitch, yaw, dyn.euler_rates(roll, pitch, w), dyn.tilt(r_ib), pix, visible,
                  in_margin, uv_true, ft.features(uv_true, s.a_d, cam.f))


def _estimate(tr: _Truth, drift: np.ndarray, yaw_drift: np.ndarray, z: np.ndarray, s: _Setup) -> _Estimate:
    """The SLAM-like estimate: truth + drift + white noise (``z``: this step's standard normals)."""
    cam, nz, col = s.cam, s.config.control.noise, NOISE_COLUMNS
    drift = drift + s.pos_rw * z[:, col["drift"]]
    yaw_drift = yaw_drift + s.yaw_rw * z[:, col["yaw_drift"]][:, 0]
    p_est = tr.p + drift + nz.position_sigma_m * z[:, col["position"]]
    att_noise = s.att_sigma * z[:, col["attitude"]]
    yaw_est = tr.yaw + yaw_drift + att_noise[:, 2]
    r_est = dyn.quat_to_rot(dyn.quat_from_euler(tr.roll + att_noise[:, 0], tr.pitch + att_noise[:, 1], yaw_est))
    t_ic_est = p_est + r_est @ cam.t_BC
    yaw_v = yaw_est + cam.yaw_on_body
    uv = ft.virtual_pixels(ft.virtual_points(s.corners, t_ic_est, yaw_v), cam.f)
    # camera velocity = body velocity + w x offset (zero with the default mount)
    v_cam = tr.v + np.einsum("nij,nj->ni", tr.r_ib, np.cross(tr.w, cam.t_BC))
    v_est = v_cam + nz.velocity_sigma_m_s * z[:, col["velocity"]]
    v_v = np.einsum("nji,nj->ni", dyn.rot_z(yaw_v), v_est)
    return _Estimate(uv, ft.features(uv, s.a_d, cam.f), ft.yaw_feature(uv), v_v, p_est, v_est, yaw_v, drift,
                     yaw_drift)


def _desired_features(phase: np.ndarray, t: float, t_switch: np.ndarray, s: _Setup) -> tuple[np.ndarray, np.ndarray]:
    """q_d and its rate: the hover (phase 0), then the touch-down ramp of the desired depth (phase 1)."""
    n, z_star, speed = phase.shape[0], s.config.control.desired_depth_m, s.sim.descent_speed_m_s
    q_d = np.zeros((n, 3))
    q_d_rate = np.zeros((n, 3))
    descending = phase == 1
    q_d[:, 2] = np.where(descending, 1.0 - speed * (t - t_switch) / z_star, 1.0)
    q_d_rate[:, 2] = np.where(descending, -speed / z_star, 0.0)
    return q_d, q_d_rate


def _approach_force(est: _Estimate, goal_z: np.ndarray, s: _Setup) -> np.ndarray:
    """Net force (N, 3) in NED flying towards the point above the site on the SLAM pose (approach phase).

    A cascaded P-position / P-velocity law: wanted velocity ``k_pos (goal - p_est)``, its horizontal
    part limited to ``speed_m_s`` and its vertical part to ``climb_speed_m_s``; force
    ``m k_vel (v_wanted - v_est)``. The goal is above the site centre at ``goal_z`` (the altitude
    the run had when it entered the approach, at least ``min_height_m`` above the site).
    """
    a = s.config.control.approach
    goal = np.column_stack([np.repeat(s.center_ned[None, :2], goal_z.shape[0], axis=0), goal_z])
    v_want = a.k_pos_1_s * (goal - est.p)
    horiz = np.linalg.norm(v_want[:, :2], axis=1)
    v_want[:, :2] *= (np.minimum(horiz, a.speed_m_s) / np.maximum(horiz, 1e-12))[:, None]
    v_want[:, 2] = np.clip(v_want[:, 2], -a.climb_speed_m_s, a.climb_speed_m_s)
    return s.params.mass_kg * a.k_vel_1_s * (v_want - est.v)


def _command(tr: _Truth, est: _Estimate, q_d: np.ndarray, q_d_rate: np.ndarray, e_i: np.ndarray,
             prev_att_d: np.ndarray | None, torque_prev: np.ndarray, qpsi_d: np.ndarray, running: np.ndarray,
             first: bool, phase: np.ndarray, goal_z: np.ndarray, d_hat: np.ndarray, s: _Setup) -> _Command:
    """The IBVS law (or the approach law) with the disturbance estimate removed, and the attitude loop."""
    c, params, gains, dt = s.config.control, s.params, s.gains, s.dt
    z_star = c.desired_depth_m
    e = est.q - q_d
    # psi' of V is taken as the gyro z rate (equal to the Euler yaw rate when level): the exact
    # Euler rate (sin(phi) q + cos(phi) r) / cos(theta) couples pitch-rate transients into S and
    # made the cascade oscillate at the control rate.
    psi_rate = tr.w[:, 2]
    # psi'' from the model (last yaw torque), not a finite difference: differencing the Euler
    # yaw rate feeds roll/pitch-rate transients back into S' and made the loop chatter.
    psi_acc = (torque_prev[:, 2] - (tr.w[:, 0] * tr.w[:, 1] * (params.inertia[1] - params.inertia[0]))) \
        / params.inertia[2]
    e_dot = ibvs.error_rate(est.q, q_d_rate, est.v_v, psi_rate, z_star)
    force_v, e_f = ibvs.control_force(e, e_dot, e_i, psi_rate, psi_acc, params.mass_kg, gains)
    lyap = ibvs.lyapunov(e_f, e_i, gains.K_i)
    to_v = dyn.rot_z(est.yaw_v)          # V -> inertial; its transpose turns NED forces into V
    approaching = phase == APPROACH
    if approaching.any():
        force_v = np.where(approaching[:, None], np.einsum("nji,nj->ni", to_v, _approach_force(est, goal_z, s)),
                           force_v)
    force_v = force_v - np.einsum("nji,nj->ni", to_v, d_hat)   # zero unless control.disturbance.observer
    thrust, roll_d, pitch_d, sat = ibvs.thrust_attitude(force_v, s.cam.yaw_on_body, params.mass_kg, params.gravity,
                                                        params.thrust_min_n, params.thrust_max_n, gains.max_tilt_rad)
    # Anti-windup: integrate only unsaturated and near the hover (integral separation). The
    # transient's e_f = K_e e(0) would otherwise leave a slow K_i mode (~K_i/K_p = 0.02 /s) that
    # holds the error near 1 px for tens of seconds.
    e_px_est = np.linalg.norm((est.q - q_d) * s.px_scale, axis=1)
    integrate = running & ~sat & (e_px_est < c.integral_zone_px) & ~approaching
    e_i = e_i + np.where(integrate[:, None], e_f * dt, 0.0)
    att_d = np.stack([roll_d, pitch_d], axis=1)
    att_d_rate = (att_d - prev_att_d) / dt if prev_att_d is not None else np.zeros_like(att_d)
    sym = math.radians(c.yaw_symmetry_deg)
    if first and sym > 0:   # a square looks the same every `sym`: turn to the nearest alignment
        qpsi_d = qpsi_d + sym * np.round(ft.wrap_angle(est.q_psi - qpsi_d) / sym)
    yaw_err = ft.wrap_angle(est.q_psi - qpsi_d)
    torque = ibvs.attitude_torque(roll_d - tr.roll, att_d_rate[:, 0] - tr.rates[:, 0], pitch_d - tr.pitch,
                                  att_d_rate[:, 1] - tr.rates[:, 1], yaw_err, psi_rate, gains, params.torque_max)
    return _Command(thrust, torque, roll_d, pitch_d, e, e_f, e_i, lyap, att_d, qpsi_d)


def _filter_error(filt_vec: np.ndarray, q: np.ndarray, restart: np.ndarray, s: _Setup) -> np.ndarray:
    """Low-pass the estimated feature error vector (px-equivalent) for the switch: noise averages out.

    ``restart``: runs entering IBVS now start the filter at their current error."""
    e_vec = (q - _HOVER_Q) * s.px_scale
    return np.where(restart[:, None], e_vec, filt_vec + s.alpha * (e_vec - filt_vec))


def _last_above(last_above: np.ndarray, last_above_settle: np.ndarray, ibvs_phase: np.ndarray, e_px_true: np.ndarray,
                e_px_start: np.ndarray, t: float, s: _Setup) -> tuple[np.ndarray, np.ndarray]:
    """End times of the last IBVS step above the stable error and above the settling fraction of the start."""
    t_next = t + s.dt
    last_above = np.where(ibvs_phase & (e_px_true >= s.sim.stable_error_px), t_next, last_above)
    last_above_settle = np.where(ibvs_phase & (e_px_true >= s.sim.settling_fraction * e_px_start), t_next,
                                 last_above_settle)
    return last_above, last_above_settle


def _stop_codes(k: int, running: np.ndarray, ibvs_phase: np.ndarray, descending: np.ndarray, tr: _Truth,
                approach_on: bool, s: _Setup) -> np.ndarray:
    """Why each run stops at this step (a ``_CODE``), 0 if it goes on; the first condition that holds wins.

    With the approach phase on, a site out of view or lost corners are not failures (the approach
    flies back into view)."""
    n = running.shape[0]
    stop = np.zeros(n, int)
    if not approach_on:
        stop = np.where(running & (k == 0) & ~tr.visible, _CODE["site_not_in_view"], stop)
        stop = np.where(running & (stop == 0) & ibvs_phase & ~tr.visible, _CODE["corners_lost"], stop)
    stop = np.where(running & (stop == 0) & (tr.tilt > math.radians(s.sim.abort_tilt_deg)), _CODE["tilt_limit"], stop)
    on_ground = tr.p[:, 2] >= s.ground_z_ned
    stop = np.where(running & (stop == 0) & on_ground, np.where(descending, _CODE["touchdown"],
                                                                _CODE["ground_contact"]), stop)
    return np.where(running & (stop == 0) & (k == s.steps), _CODE["timeout"], stop)


def _record_end(out: dict[str, np.ndarray], stop: np.ndarray, t: float, tr: _Truth,
                s: _Setup) -> dict[str, np.ndarray]:
    """End time of the runs stopping now; touch-down distance from the site centre and speed of those landing."""
    landed = stop == _CODE["touchdown"]
    p_enu = dyn.ned_to_enu(tr.p)
    return {**out, "t_end": np.where(stop > 0, t, out["t_end"]),
            "td_err": np.where(landed, np.hypot(*(p_enu[:, :2] - s.center_world[:2]).T), out["td_err"]),
            "td_speed": np.where(landed, np.linalg.norm(tr.v, axis=1), out["td_speed"])}


def _switch_due(ibvs_phase: np.ndarray, ending: np.ndarray, filt_px: np.ndarray, held: np.ndarray,
                s: _Setup) -> tuple[np.ndarray, np.ndarray]:
    """Runs whose filtered error has stayed below the switch threshold for ``switch_hold_s``; the hold timers."""
    below = ibvs_phase & ~ending & (filt_px < s.sim.switch_error_px)
    held = np.where(below, held + s.dt, 0.0)
    return below & (held >= s.sim.switch_hold_s), held


def _record_switch(out: dict[str, np.ndarray], switch: np.ndarray, e_px_true: np.ndarray, yaw_err_true: np.ndarray,
                   last_above: np.ndarray, last_above_settle: np.ndarray, s: _Setup) -> dict[str, np.ndarray]:
    """The IBVS-phase metrics of the runs switching to touch-down now."""
    ok = e_px_true < s.sim.stable_error_px
    return {**out, "final_px": np.where(switch, e_px_true, out["final_px"]),
            "final_yaw": np.where(switch, np.degrees(np.abs(yaw_err_true)), out["final_yaw"]),
            "stab": np.where(switch & ok, last_above, out["stab"]),
            "settle": np.where(switch, last_above_settle, out["settle"])}


def _integrate(x: np.ndarray, cmd: _Command, torque: np.ndarray, yaw: np.ndarray, gust: np.ndarray,
               s: _Setup) -> tuple[np.ndarray, np.ndarray]:
    """The rigid body over one control period with the inputs held; returns the state and the torque applied."""
    x_new = x.copy()
    if s.sim.attitude == "ideal":   # roll/pitch follow the command at once; yaw stays dynamic
        x_new[:, 6:10] = dyn.quat_from_euler(cmd.roll_d, cmd.pitch_d, yaw)
        x_new[:, 10:12] = 0.0
        torque = torque.copy()
        torque[:, :2] = 0.0
    for _ in range(s.n_sub):
        force_d = s.wind.force(x_new[:, 3:6], gust)
        x_new = dyn.rk4_step(x_new, s.sim.dynamics_dt_s, cmd.thrust, torque, force_d, s.params)
    return x_new, torque


def _log_row(t: float, x: np.ndarray, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, thrust: np.ndarray,
             torque: np.ndarray, q: np.ndarray, e: np.ndarray, e_f: np.ndarray, e_i: np.ndarray, lyap: np.ndarray,
             q_true: np.ndarray, e_px_true: np.ndarray, yaw_err: np.ndarray, pix: np.ndarray, uv: np.ndarray,
             phase: np.ndarray, d_hat: np.ndarray) -> dict[str, np.ndarray]:
    return {"t": np.full(x.shape[0], t), "p_world": dyn.ned_to_enu(x[:, 0:3]), "v_world": dyn.ned_to_enu(x[:, 3:6]),
            "euler_ned": np.stack([roll, pitch, yaw], axis=1), "w_body": x[:, 10:13].copy(), "thrust": thrust,
            "torque": torque, "q": q, "e_q": e, "e_f": e_f, "e_i": e_i.copy(), "lyapunov": lyap, "q_true": q_true,
            "e_px_true": e_px_true, "yaw_err_true": yaw_err, "corner_px": pix, "virtual_uv": uv, "phase": phase.copy(),
            "d_hat_world": dyn.ned_to_enu(d_hat)}


def _stack(rows: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """List of per-step dicts of (N, ...) -> dict of (steps, N, ...) arrays."""
    if not rows:
        return {}
    return {k: np.stack([r[k] for r in rows]) for k in rows[0]}


def sample_starts(base_world: np.ndarray, runs: int, mc: MonteCarloCfg, seed: int, first_run: int = 0) -> np.ndarray:
    """Monte Carlo starts: uniform disc around base (x, y), uniform +-dz, +-yaw (``control.montecarlo``).

    Run i's start comes from its own stream (seed, first_run + i): it does not depend on ``runs``.
    """
    draws = np.array([run_generator(seed, first_run + i, START_STREAM).uniform(0.0, 1.0, 4) for i in range(runs)])
    draws = draws.reshape(runs, 4)
    radius = mc.start_radius_m * np.sqrt(draws[:, 0])
    ang = 2 * np.pi * draws[:, 1]
    out = np.repeat(np.asarray(base_world, float)[None, :4], runs, axis=0)
    out[:, 0] += radius * np.cos(ang)
    out[:, 1] += radius * np.sin(ang)
    out[:, 2] += mc.start_dz_m * (2 * draws[:, 2] - 1)
    out[:, 3] += mc.start_yaw_deg * (2 * draws[:, 3] - 1)
    return out


def resolve_start(target: Target, config: Config, scenario: int | None = None,
                  start: tuple[float, ...] | None = None, offset: tuple[float, ...] | None = None) -> np.ndarray:
    """The (4,) world start (x, y, z m, yaw deg; ENU) a user asked for; at most one of the three.

    ``--scenario N``: the paper's start position, absolute in the run's world frame (as in ``slz synth``).
    ``--start x,y,z[,yaw]``: an absolute world position (ENU, the run's world frame), as in ``slz synth``.
    ``--offset x,y,z[,yaw]``: an offset from the site centre (world x, y, up), since a run's world
    frame (first camera, odometry) is arbitrary. None: the configured offset
    ``control.sim.start_offset_m`` (the paper's scenario 1 geometry). Yaw: degrees from world +x,
    counter-clockwise (ENU), the convention of every slz output.
    """
    if sum(v is not None for v in (scenario, start, offset)) > 1:
        raise ConfigError("--start", "give one of --scenario, --start or --offset")
    if scenario is not None:
        if scenario not in SCENARIOS:
            raise ConfigError("--scenario", f"must be one of {sorted(SCENARIOS)}, got {scenario}")
        return _above_site(np.array([*SCENARIOS[scenario], 0.0]), target, config.uav, "--scenario")
    if start is not None:
        if len(start) not in (3, 4):
            raise ConfigError("--start", f"expected x,y,z[,yaw], got {len(start)} values")
        return _above_site(np.array([*start[:3], start[3] if len(start) > 3 else 0.0], float), target, config.uav,
                           "--start")
    off = offset if offset is not None else config.control.sim.start_offset_m
    if len(off) not in (3, 4):
        raise ConfigError("--offset", f"expected x,y,z[,yaw], got {len(off)} values")
    key = "--offset" if offset is not None else "control.sim.start_offset_m"
    return _above_site(start_from_offsets(target, np.array(off, float))[0], target, config.uav, key)


def _above_site(start: np.ndarray, target: Target, uav: UavCfg, key: str) -> np.ndarray:
    """``start`` when the UAV's body is clear of the site there; else a ConfigError naming ``key``.

    At or below ``site z + uav.size_m[2] / 2`` the simulation would stop at its first step on ground
    contact: nothing to simulate, and no landing to report.
    """
    clear = uav.size_m[2] / 2
    height = float(start[2] - target.center_world[2])
    if not height > clear:
        raise ConfigError(key, f"the start is {height:.3g} m above the site (z {target.center_world[2]:.3g} m); the "
                               f"UAV's body touches the ground below {clear:.3g} m (uav.size_m[2] / 2): start higher")
    return start
