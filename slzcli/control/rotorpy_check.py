"""An independent check of slz's landing simulation: the same IBVS controller flying RotorPy's multirotor.

RotorPy (PyPI ``rotorpy``, ``pip install 'slz[rotorpy]'``; Folk et al., UPenn) is a maintained
multirotor simulator with rotor dynamics (first-order motor lag, speed limits), control allocation to
four rotors, and an aerodynamic model (parasitic drag, rotor drag, induced inflow, translational
lift) fed by its wind profiles. ``simulate(..., plant=RotorPyPlant(...))`` runs slz's whole closed
loop (SLAM-like pose, features from the projected square corners, the law, the attitude PD, the
disturbance observer, the phase logic and metrics) unchanged and only replaces slz's rigid body
(``dynamics.rk4_step`` with linear drag) by RotorPy's ``Multirotor.step`` under the ``cmd_ctbm``
abstraction: the collective thrust and body moments slz's own simulator feeds its dynamics.

The vehicle: slz's Bebop 2 mass and inertia (``uav``), its thrust range mapped onto the rotor speed
range, rotor hubs on the body diagonals at half the body size; motor lag, torque/thrust ratio and
all aerodynamic coefficients are RotorPy's own (``rotorpy/vehicles/hummingbird_params.py``, the
vehicle its models were identified on; the Bebop 2's are unpublished). Frames: slz's control state
is NED / FRD; RotorPy's world is z-up (ENU here) and its body FLU.

rotorpy is imported lazily: slz does not depend on it (benchmarks/ibvs_rotorpy.py, tests skip
without it).
"""

from __future__ import annotations

import math
from typing import Any, TypedDict

import numpy as np

from slzcli.config import ControlCfg, UavCfg
from slzcli.control import dynamics as dyn
from slzcli.errors import SlzError

FRD_FLU = np.diag([1.0, -1.0, -1.0])
"""Body FRD <-> FLU (self-inverse)."""
ROTOR_SPEED_MAX_RAD_S = 1500.0
"""rad/s; RotorPy hummingbird_params rotor_speed_max; k_eta is chosen so that 4 k_eta w_max^2 = uav.thrust_max_n."""
UPSTREAM = {   # rotorpy/vehicles/hummingbird_params.py (RotorPy 3.0.0)
    "tau_m": 0.005,          # s, motor response time
    "k_m_over_k_eta": 1.36e-07 / 5.57e-06,   # m, yaw moment per thrust of a rotor
    "c_Dx": 0.5e-2, "c_Dy": 0.5e-2, "c_Dz": 1e-2,   # N/(m/s)^2, parasitic drag
    "k_d": 1.19e-04, "k_z": 2.32e-04,           # kg/rad, rotor drag and induced inflow
    "k_h": 3.39e-3, "k_flap": 0.0,              # kg/m, translational lift; flapping moment
}


class RotorPyMissing(SlzError):
    """The optional rotorpy package is not installed."""


def _rotorpy() -> tuple[Any, Any, Any]:
    try:
        from rotorpy.vehicles.multirotor import Multirotor
        from rotorpy.wind.default_winds import ConstantWind, NoWind
    except ImportError as exc:   # an optional extra
        raise RotorPyMissing(f"rotorpy is not installed ({exc}); pip install 'slz[rotorpy]'") from exc
    return Multirotor, ConstantWind, NoWind


class QuadParams(TypedDict):
    """RotorPy's ``quad_params`` (``rotorpy/vehicles/hummingbird_params.py``): SI units, FLU body."""

    mass: float
    Ixx: float
    Iyy: float
    Izz: float
    Ixy: float
    Iyz: float
    Ixz: float
    num_rotors: int
    rotor_radius: float
    rotor_pos: dict[str, np.ndarray]
    rotor_directions: np.ndarray
    rI: np.ndarray
    c_Dx: float
    c_Dy: float
    c_Dz: float
    k_eta: float
    k_m: float
    k_d: float
    k_z: float
    k_h: float
    k_flap: float
    tau_m: float
    rotor_speed_min: float
    rotor_speed_max: float
    motor_noise_std: float


def quad_params(u: UavCfg) -> QuadParams:
    """RotorPy's ``quad_params`` for slz's UAV (``uav``) with RotorPy's own motor and aero coefficients."""
    k_eta = u.thrust_max_n / (4.0 * ROTOR_SPEED_MAX_RAD_S ** 2)
    h = u.size_m[0] / 2.0 / math.sqrt(2.0)        # hub x, y: arm of half the body size along the diagonals
    return {
        "mass": u.mass_kg, "Ixx": u.inertia_kg_m2[0], "Iyy": u.inertia_kg_m2[1], "Izz": u.inertia_kg_m2[2],
        "Ixy": 0.0, "Iyz": 0.0, "Ixz": 0.0,
        "num_rotors": 4, "rotor_radius": 0.1,
        "rotor_pos": {"r1": np.array([h, h, 0.0]), "r2": np.array([h, -h, 0.0]),
                      "r3": np.array([-h, -h, 0.0]), "r4": np.array([-h, h, 0.0])},
        "rotor_directions": np.array([1, -1, 1, -1]), "rI": np.zeros(3),
        "c_Dx": UPSTREAM["c_Dx"], "c_Dy": UPSTREAM["c_Dy"], "c_Dz": UPSTREAM["c_Dz"],
        "k_eta": k_eta, "k_m": k_eta * UPSTREAM["k_m_over_k_eta"],
        "k_d": UPSTREAM["k_d"], "k_z": UPSTREAM["k_z"], "k_h": UPSTREAM["k_h"], "k_flap": UPSTREAM["k_flap"],
        "tau_m": UPSTREAM["tau_m"],
        "rotor_speed_min": math.sqrt(u.thrust_min_n / (4.0 * k_eta)), "rotor_speed_max": ROTOR_SPEED_MAX_RAD_S,
        "motor_noise_std": 0.0,
    }


def equivalent_drag_kg_s(params: QuadParams, mass_kg: float, gravity: float, airspeed_m_s: float) -> float:
    """RotorPy's horizontal drag near the hover as slz's linear ``control.wind.drag_kg_s``.

    Rotor drag ``H = -w k_d v`` on each of the four rotors at the hover speed w, plus the parasitic
    ``c_D |v| v`` linearised at ``airspeed_m_s``. With RotorPy's (hummingbird) coefficients this is
    ~0.5 kg/s for slz's Bebop 2, five times slz's default 0.1 kg/s: the same wind pushes harder.
    """
    hover = math.sqrt(mass_kg * gravity / (4.0 * params["k_eta"]))
    return 4.0 * params["k_d"] * hover + params["c_Dx"] * airspeed_m_s


def ned_to_rotorpy(x: np.ndarray) -> dict[str, np.ndarray]:
    """One slz state row (13,) NED/FRD -> RotorPy's state dict (ENU world, FLU body, quaternion x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    r = dyn.ENU_NED @ dyn.quat_to_rot(x[None, 6:10])[0] @ FRD_FLU
    return {"x": dyn.ENU_NED @ x[0:3], "v": dyn.ENU_NED @ x[3:6], "q": Rotation.from_matrix(r).as_quat(),
            "w": FRD_FLU @ x[10:13]}


def rotorpy_to_ned(state: dict[str, np.ndarray]) -> np.ndarray:
    """RotorPy's state dict -> one slz state row (13,) NED/FRD, quaternion w first."""
    from scipy.spatial.transform import Rotation

    r = dyn.ENU_NED @ Rotation.from_quat(state["q"]).as_matrix() @ FRD_FLU
    xyzw = Rotation.from_matrix(r).as_quat()
    return np.concatenate([dyn.ENU_NED @ state["x"], dyn.ENU_NED @ state["v"], [xyzw[3], *xyzw[:3]],
                           FRD_FLU @ state["w"]])


class RotorPyPlant:
    """``simulate``'s ``plant``: N independent RotorPy multirotors, each holding the command for one control period.

    ``wind_m_s``: RotorPy's ``ConstantWind`` (world x, y, up; m/s), None = its ``NoWind``. ``aero``: RotorPy's
    aerodynamic wrenches on (its drag replaces slz's ``control.wind.drag_kg_s``). Rotor speeds are carried from
    step to step (the motors' lag is part of what is checked), starting at the hover speed.
    """

    def __init__(self, control: ControlCfg, uav: UavCfg, *, wind_m_s: tuple[float, float, float] | None = None,
                 aero: bool = True):
        multirotor, constant_wind, no_wind = _rotorpy()
        self.params = quad_params(uav)
        self.vehicle = multirotor(self.params, control_abstraction="cmd_ctbm", aero=aero, enable_ground=False)
        self.wind = no_wind() if wind_m_s is None else constant_wind(*wind_m_s)
        self.dt = control.sim.control_dt_s
        hover = math.sqrt(uav.mass_kg * self.vehicle.g / (4.0 * self.params["k_eta"]))
        self.hover_speed = hover
        self.rotor_speeds: np.ndarray | None = None
        self.t = 0.0

    def __call__(self, x: np.ndarray, thrust: np.ndarray, torque: np.ndarray) -> np.ndarray:
        n = x.shape[0]
        if self.rotor_speeds is None:
            self.rotor_speeds = np.full((n, 4), self.hover_speed)
        out = x.copy()
        for i in range(n):   # RotorPy's Multirotor is one vehicle; a check flies a handful of runs
            state = ned_to_rotorpy(x[i])
            state["rotor_speeds"] = self.rotor_speeds[i].copy()
            state["wind"] = np.asarray(self.wind.update(self.t, state["x"]), float)
            control = {"cmd_thrust": float(thrust[i]), "cmd_moment": FRD_FLU @ torque[i]}
            new = self.vehicle.step(state, control, self.dt)
            self.rotor_speeds[i] = new["rotor_speeds"]
            out[i] = rotorpy_to_ned(new)
        self.t += self.dt
        return out
