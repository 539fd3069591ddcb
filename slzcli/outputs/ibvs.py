"""Files of `slz land simulate`: the landing.json it reads, and RUN/ibvs/ it writes (atomically).

Reading: a run folder holding ``landing.json`` (DESIGN.md contract) or that file itself. A
recording is not accepted here: the site comes from ``slz detect``.
Writing: ``trajectory.csv``, ``features.csv``, ``metrics.json`` for one run;
``montecarlo.json`` (+ ``montecarlo_runs.csv``) for a batch. Figures are in ``ibvs_plots.py``.
The folder is an ``output_dir`` kind (``simulate``, ``montecarlo``; one folder may hold one of
each): written whole under a temporary name and put in place at the end, never into a folder
slz did not write, never over a file it did not write.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from slzcli.config import CameraCfg
from slzcli.errors import DatasetError, NoSiteFound
from slzcli.outputs.files import atomic_path, write_json, write_text
from slzcli.types import SimResult, Target


def landing_path(path: Path) -> Path:
    """RUN folder or landing.json -> the landing.json path; anything else is a clear error."""
    path = Path(path)
    if path.is_dir():
        candidate = path / "landing.json"
        if candidate.is_file():
            return candidate
        raise DatasetError(path, "no landing.json in this folder; run `slz detect` on the recording first, "
                                 "then `slz land simulate RUN`")
    if path.is_file() and path.suffix == ".json":
        return path
    if path.exists():
        raise DatasetError(path, "not a run folder or landing.json (a recording needs `slz detect` first, "
                                 "then `slz land simulate RUN`)")
    raise DatasetError(path, "not found")


def read_target(path: Path, footprint_m: tuple[float, ...]) -> Target:
    """The landing square of a landing.json; no site -> NoSiteFound.

    Parsed only: whether the corners are this UAV's Eq. 10 square is ``control.simulate.check_target``.
    """
    file = landing_path(path)
    from slzcli.bounds import load_json

    doc = load_json(file, "landing.json")
    if not isinstance(doc, dict) or "status" not in doc:
        raise DatasetError(file, "missing key 'status' (expected the landing.json of `slz detect`)")
    if doc["status"] == "no_safe_site":
        raise NoSiteFound(f"{file}: status no_safe_site ({doc.get('reason', 'no reason given')}); "
                          "there is no site to land on")
    if doc["status"] != "site":
        raise DatasetError(file, f"status: expected 'site' or 'no_safe_site', got {doc['status']!r}")
    site = doc.get("site")
    if not isinstance(site, dict):
        raise DatasetError(file, "site: missing or not an object")
    try:
        center = np.asarray(site["center_world"], float).reshape(3)
    except (KeyError, TypeError, ValueError) as err:
        raise DatasetError(file, "site.center_world: expected [x, y, z] metres") from err
    corners = site.get("corners_world")
    if corners is None:   # Eq. 10 from the centre and the footprint
        signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
        corners_arr = np.repeat(center[None], 4, axis=0)
        corners_arr[:, :2] += signs * np.asarray(footprint_m[:2], float)
    else:
        try:
            corners_arr = np.asarray(corners, float).reshape(4, 3)
        except (TypeError, ValueError) as err:
            raise DatasetError(file, "site.corners_world: expected four [x, y, z] points") from err
    if not (np.isfinite(center).all() and np.isfinite(corners_arr).all()):
        raise DatasetError(file, "site: centre or corners are not finite numbers")
    return Target(center, corners_arr)


@contextmanager
def output_folder(out: Path, landing: Path, runs: int) -> Iterator[Path]:
    """A temporary folder to write the simulation's files into; put in place at ``out`` when the block ends.

    ``out`` may not be or hold the landing.json read; slz replaces only its own earlier results there.
    """
    from slzcli.outputs import output_dir, run_lock

    output_dir.refuse_inputs(out, [landing])
    kind = output_dir.SIMULATE if runs == 1 else output_dir.MONTECARLO
    output_dir.check_names(output_dir.inspect(out, kind), kind.names)  # before the simulation runs
    with run_lock.claim(out), output_dir.build(out, kind, replace=True) as tmp:
        yield tmp


def write_single(out_dir: Path, result: SimResult, metrics: Mapping[str, object], target: Target,
                 cam: CameraCfg) -> None:
    """The files of one logged landing: the tables, metrics.json and the three figures."""
    from slzcli.outputs import ibvs_plots

    write_run(out_dir, result, metrics, cam.cx, cam.cy)
    ibvs_plots.image_plane(out_dir / "image_plane.png", result, cam.width, cam.height, cam.cx, cam.cy)
    ibvs_plots.feature_error(out_dir / "feature_error.png", result)
    ibvs_plots.trajectory_3d(out_dir / "trajectory_3d.png", result, target)


def _csv(header: list[str], columns: list[np.ndarray]) -> str:
    data = np.column_stack([np.asarray(c, float).reshape(len(c), -1) for c in columns])
    buf = io.StringIO()
    np.savetxt(buf, data, delimiter=",", header=",".join(header), comments="", fmt="%.6g")
    return buf.getvalue()


def write_run(out_dir: Path, result: SimResult, metrics: Mapping[str, object], cx: float, cy: float,
              i: int = 0) -> list[Path]:
    """trajectory.csv, features.csv and metrics.json of run i of a logged simulation."""
    log = result.log
    if not log:
        raise ValueError("write_run needs a simulation run with log=True")
    L = {k: v[:, i] for k, v in log.items()}
    # One yaw convention in every output: ENU, degrees from world +x counter-clockwise (as --start and
    # metrics.json's start_world); the controller's NED heading (from north, clockwise) is 90 deg - that.
    # Roll and pitch are the FRD body's (right wing down, nose up positive), which the frame change keeps.
    euler = np.degrees(L["euler_ned"])
    euler[:, 2] = (90.0 - euler[:, 2] + 180.0) % 360.0 - 180.0
    traj = _csv(["t_s", "x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg", "vx_m_s", "vy_m_s", "vz_m_s",
                 "p_rad_s", "q_rad_s", "r_rad_s", "thrust_n", "tau_x_n_m", "tau_y_n_m", "tau_z_n_m", "phase",
                 "dist_x_n", "dist_y_n", "dist_z_n"],
                [L["t"], L["p_world"], euler, L["v_world"], L["w_body"], L["thrust"],
                 L["torque"], L["phase"], L["d_hat_world"]])
    corner_cols = [f"{a}{k}_px" for k in range(4) for a in ("u", "v")]
    virt_cols = [f"virtual_{a}{k}_px" for k in range(4) for a in ("u", "v")]
    feats = _csv(["t_s", "q_x", "q_y", "q_z", "e_qx", "e_qy", "e_qz", "e_px_true", "yaw_error_deg", "lyapunov",
                  *corner_cols, *virt_cols],
                 [L["t"], L["q"], L["e_q"], L["e_px_true"], np.degrees(L["yaw_err_true"]), L["lyapunov"],
                  L["corner_px"].reshape(len(L["t"]), -1),
                  (L["virtual_uv"] + np.array([cx, cy])).reshape(len(L["t"]), -1)])
    paths = [out_dir / "trajectory.csv", out_dir / "features.csv", out_dir / "metrics.json"]
    write_text(paths[0], traj)
    write_text(paths[1], feats)
    write_json(paths[2], metrics)
    return paths


MC_COLUMNS = ("stabilisation_time_s", "settling_time_s", "switch_time_s", "final_feature_error_px",
              "touchdown_error_m", "landing_time_s", "max_tilt_deg", "handover_time_s", "approach_time_s",
              "ibvs_time_s", "descent_time_s", "recoveries")
MC_HEADER = ("run", "success", "x0_m", "y0_m", "z0_m", "yaw0_deg", *MC_COLUMNS, "reason")


def montecarlo_lines(result: SimResult, first_run: int = 0) -> list[str]:
    """One CSV line per run of a (chunk) result; run numbers start at ``first_run``."""
    lines = []
    for i in range(len(result.reason)):
        vals = [str(first_run + i), str(int(result.success[i])), *(f"{v:.4f}" for v in result.starts_world[i]),
                *(f"{getattr(result, c)[i]:.6g}" for c in MC_COLUMNS), str(result.reason[i])]
        lines.append(",".join(vals))
    return lines


@contextmanager
def montecarlo_rows(out_dir: Path) -> Iterator[Callable[[SimResult, int], None]]:
    """``montecarlo_runs.csv`` written chunk by chunk as the batch runs (``add(result, first_run)``).

    It is built under a temporary name and renamed when the batch ends: a stopped batch leaves no
    half table behind, and no run's result waits in memory to be written.
    """
    with atomic_path(out_dir / "montecarlo_runs.csv") as tmp, open(tmp, "w") as fh:
        fh.write(",".join(MC_HEADER) + "\n")

        def add(result: SimResult, first_run: int) -> None:
            fh.write("".join(line + "\n" for line in montecarlo_lines(result, first_run)))
        yield add


def write_montecarlo(out_dir: Path, result: SimResult, summary: Mapping[str, object],
                     rows_written: bool = False) -> list[Path]:
    """montecarlo.json (the aggregate) and montecarlo_runs.csv (one row per run, unless already streamed)."""
    paths = [out_dir / "montecarlo.json", out_dir / "montecarlo_runs.csv"]
    if not rows_written:
        write_text(paths[1], "\n".join([",".join(MC_HEADER), *montecarlo_lines(result)]) + "\n")
    write_json(paths[0], summary)
    return paths
