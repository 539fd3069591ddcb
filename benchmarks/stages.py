"""Per-frame time of the detection core on one core: terrain maps + fuzzy score + landing mask (issue 18).

What is timed is what ``slz detect`` does for a detection frame (slzcli/pipeline.py): the depth-noise
update (``NoiseTracker.update``, ``terrain.noise: auto``, the default), ``posed_maps`` (``frame_maps``),
``Fusion``'s score (``FuzzyScorer``) and ``mask_score`` (plan-view footprint filter, column rule).
The pipeline's own "maps" time excludes the noise update; it is reported as its own column and in
the total.

Frames: ``slz synth`` renders (default sensor: D435-like stereo, 640x480) of three scenes from 3, 5
and 8 m, with their true poses (as SLAM gives them), and the ten real RealSense frames
(../shared/data/realsense_floor, the documented mount of tests/terrain/test_terrain.py), when present.

Each frame is run ``--runs`` times by the code of ``--before`` (a git revision: its terrain/ and
scoring/ modules are loaded from ``git show`` into this process, as benchmarks/slam_robustness.py
does) and by the current code, alternating; per-frame medians, then the median and the max over
frames. Both CPU time of the thread (``time.thread_time``: the machine is shared, wall time swings with
the other processes) and wall time. The outputs of the two are compared on every frame (max
difference of each map, the score, and mask pixels that differ).

References measured in the same process:
- the paper, 1367 ms a frame for detection (Table 2, as quoted in the issue);
- the obvious tool: Open3D ``estimate_normals`` on the frame's point cloud (hybrid radius 0.15 m,
  max 30 neighbours) plus scikit-fuzzy evaluating the same rules (tests/skfuzzy_oracle.py) on the same
  maps, given as arrays (its vectorised use); a whole frame takes minutes, so it is timed on
  ``--skfuzzy-pixels`` random valid pixels and scaled to the frame's valid pixels;
- the physical floor: ``--floor-passes`` float32 passes (read + write) over the frame's depth image.

One core: OMP/OPENBLAS/MKL threads 1 (set before numpy loads) and cv2.setNumThreads(1).
Prints a table and writes benchmarks/results/stages.json. Usage:
    .venv/bin/python benchmarks/stages.py [--before 43fd46a] [--runs 5] [--profile]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import cProfile  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import pstats  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import harness  # noqa: E402
import numpy as np  # noqa: E402

harness.use_test_helpers()
REPO = harness.REPO

from slzcli.config import Config, Mount, load_config  # noqa: E402
from slzcli.sources import open_recording  # noqa: E402
from slzcli.types import Frame, Intrinsics, TerrainMaps  # noqa: E402

cv2.setNumThreads(1)

PAPER_MS = 1367.0                       # Sepahvand et al. 2024, Table 2: detection per frame
REALSENSE = harness.REALSENSE
REALSENSE_MOUNT = Mount(64.4, 19.0)     # tests/terrain/test_terrain.py: the floor plane of frame 0
SCENES = ("playground", "parking_lot", "clear_field")
ALTITUDES_M = (3, 5, 8)
CACHE = Path(tempfile.gettempdir()) / "slz_stages"
# the modules the detection core runs, in import order (a module is loaded after those it imports)
CORE_MODULES = ("slzcli.terrain.geometry", "slzcli.terrain.noise", "slzcli.terrain.limits", "slzcli.terrain.maps",
                "slzcli.scoring.closed_form", "slzcli.scoring.lut", "slzcli.scoring.mask", "slzcli.scoring")


# ----------------------------------------------------------------------------- code of a revision
@dataclasses.dataclass(frozen=True)
class Core:
    """The detection core's functions, of one revision."""

    name: str
    maps: types.ModuleType
    noise: types.ModuleType
    scoring: types.ModuleType

    # a revision from before the stages took their own config sections takes the whole Config
    def scorer(self, config: Any) -> Any:
        if hasattr(self.scoring, "MaskParams"):
            return self.scoring.get_scorer(config.scoring, config.mask)
        return self.scoring.get_scorer(config)

    def mask_params(self, config: Any) -> Any:
        return self.scoring.MaskParams.of(config) if hasattr(self.scoring, "MaskParams") else config

    def map_params(self, config: Any) -> Any:
        return self.maps.MapParams.of(config) if hasattr(self.maps, "MapParams") else config


def current_core() -> Core:
    import slzcli.scoring as scoring
    import slzcli.terrain.maps as maps
    import slzcli.terrain.noise as noise

    return Core("after", maps, noise, scoring)


def revision_core(rev: str) -> Core:
    """CORE_MODULES as they were at git revision ``rev``, loaded under their own names while they are
    executed (so they import each other's old versions), then the current ones put back."""
    current_core()   # the current modules are imported, to be put back below
    saved = {name: sys.modules.get(name) for name in CORE_MODULES}
    loaded: dict[str, types.ModuleType] = {}
    try:
        for name in CORE_MODULES:
            current = saved[name]
            is_package = current is not None and hasattr(current, "__path__")
            path = name.replace(".", "/") + ("/__init__.py" if is_package else ".py")
            src = harness.source_at(rev, path)
            mod = types.ModuleType(name)
            mod.__file__ = f"{rev}:{path}"
            if is_package:
                assert current is not None
                mod.__path__ = list(current.__path__)
                mod.__package__ = name
            else:
                mod.__package__ = name.rpartition(".")[0]
            sys.modules[name] = mod
            exec(compile(src, f"{rev}:{path}", "exec"), mod.__dict__)
            loaded[name] = mod
    finally:
        for name, mod_ in saved.items():
            if mod_ is not None:
                sys.modules[name] = mod_
    return Core("before", loaded["slzcli.terrain.maps"], loaded["slzcli.terrain.noise"], loaded["slzcli.scoring"])


# ----------------------------------------------------------------------------- frames
@dataclasses.dataclass(frozen=True)
class Case:
    """One recording's frames with the config they are mapped with."""

    name: str
    frames: list[Frame]
    config: Config


def synth_cases(frames: int, seed: int, scenes: tuple[str, ...] = SCENES) -> list[Case]:
    """The synth recordings (rendered once into CACHE), frames posed with their true poses."""
    CACHE.mkdir(exist_ok=True)
    config = load_config()
    out = []
    for scene in scenes:
        for z in ALTITUDES_M:
            path = CACHE / f"{scene}_z{z}_f{frames}_s{seed}.mcap"
            if not path.exists():
                subprocess.run([sys.executable, "-m", "slzcli.cli", "synth", scene, "-o", str(path), "--frames",
                                str(frames), "--start", f"0,0,{z}", "--path", "hover", "--seed", str(seed)],
                               check=True, cwd=REPO, capture_output=True)
            poses = np.load(str(path) + ".gt.npz")["T_world_camera"]
            with open_recording(path, config) as rec:
                fs = [dataclasses.replace(f, T_world_camera=poses[i]) for i, f in enumerate(rec.frames())]
            out.append(Case(f"{scene} {z} m", fs, config))
    return out


def realsense_case() -> Case | None:
    if not (REALSENSE / "cam_params_realsense.json").is_file():
        return None
    cam = json.loads((REALSENSE / "cam_params_realsense.json").read_text())
    k = np.array(cam["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T   # column-major
    intr = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], int(cam["width"]), int(cam["height"]))
    config = load_config()
    config = dataclasses.replace(config, camera=dataclasses.replace(config.camera, mount=REALSENSE_MOUNT))
    frames = []
    for i, png in enumerate(sorted((REALSENSE / "depth").glob("*.png"))):
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise SystemExit(f"cannot read {png}")
        depth = np.where(raw > 0, raw.astype(np.float32) * np.float32(config.sources.depth_unit_16u_m), np.nan)
        frames.append(Frame(i, i, np.zeros((*raw.shape, 3), np.uint8), depth.astype(np.float32), intr))
    return Case("realsense floor (real)", frames, config)


# ----------------------------------------------------------------------------- one frame
STAGES = ("noise", "maps", "score", "mask")


def run_frame(core: Core, frame: Frame, config: Config, scorer: Any, tracker: Any) -> tuple[dict[str, float],
                                                                                            dict[str, float], Any]:
    """(CPU ms, wall ms) per stage and the outputs (maps, score map) of one detection frame."""
    cpu: dict[str, float] = {}
    wall: dict[str, float] = {}

    def lap(name: str, fn: Callable[[], Any]) -> Any:
        c0, w0 = time.thread_time(), time.perf_counter()
        out = fn()
        cpu[name], wall[name] = (time.thread_time() - c0) * 1e3, (time.perf_counter() - w0) * 1e3
        return out

    map_params, mask_params = core.map_params(config), core.mask_params(config)
    noise = lap("noise", lambda: tracker.update(frame.depth_m))
    maps = lap("maps", lambda: core.maps.frame_maps(frame, map_params, noise))
    raw = lap("score", lambda: scorer(maps))
    sm = lap("mask", lambda: core.scoring.mask_score(scorer, raw, frame.depth_m, frame.intrinsics, mask_params,
                                                     maps.work, maps.up_camera))
    return cpu, wall, (maps, sm)


def differences(a: tuple[TerrainMaps, Any], b: tuple[TerrainMaps, Any]) -> dict[str, float]:
    """Max |a - b| of each map, the slope, the edge distance and the score; mask pixels that differ."""
    out: dict[str, float] = {}
    for name in (*TerrainMaps.NAMES, "slope_deg", "edge_distance_m"):
        x, y = getattr(a[0], name), getattr(b[0], name)
        nan_differs = int(np.count_nonzero(np.isnan(x) != np.isnan(y)))
        both = np.isfinite(x) & np.isfinite(y)
        out[name] = float(np.max(np.abs(x[both] - y[both]), initial=0.0)) + (np.inf if nan_differs else 0.0)
    out["score"] = float(np.max(np.abs(a[1].score - b[1].score)))
    out["mask_pixels"] = float(np.count_nonzero(a[1].mask != b[1].mask))
    out["block_px"] = float(a[0].work.block_px != b[0].work.block_px) if a[0].work and b[0].work else 0.0
    return out


def time_case(cores: list[Core], case: Case, runs: int) -> dict[str, Any]:
    """Per frame: median CPU and wall ms per stage for each core; and the outputs' differences."""
    per: dict[str, dict[str, list[list[float]]]] = {c.name: {"cpu": [], "wall": []} for c in cores}
    diffs: list[dict[str, float]] = []
    repeat: list[dict[str, float]] = []     # the first core against itself: run-to-run jitter
    trackers = {c.name: c.noise.NoiseTracker(case.config.terrain.noise, case.config.terrain.noise_estimate)
                for c in cores}
    scorers = {c.name: c.scorer(case.config) for c in cores}
    for frame in case.frames:
        samples: dict[str, dict[str, list[dict[str, float]]]] = {c.name: {"cpu": [], "wall": []} for c in cores}
        outputs = {}
        first = None
        # the tracker is a run's state: the first pass of a frame updates it, each repeat updates a
        # copy of it as it was before the frame, so every pass sees the noise the run would have
        before = {c.name: _copy_tracker(trackers[c.name]) for c in cores}
        for r in range(runs + 1):
            for c in cores:
                tracker = trackers[c.name] if r == 0 else _copy_tracker(before[c.name])
                cpu, wall, outputs[c.name] = run_frame(c, frame, case.config, scorers[c.name], tracker)
                if r == 1 and c is cores[0]:
                    first = outputs[c.name]
                if r > 0:       # the first pass warms caches
                    samples[c.name]["cpu"].append(cpu)
                    samples[c.name]["wall"].append(wall)
        for c in cores:
            for kind in ("cpu", "wall"):
                per[c.name][kind].append([statistics.median(s[k] for s in samples[c.name][kind]) for k in STAGES])
        if len(cores) == 2:
            diffs.append(differences(outputs[cores[0].name], outputs[cores[1].name]))
        if first is not None and runs > 1:
            repeat.append(differences(first, outputs[cores[0].name]))
    return {"frames": len(case.frames), "per_frame_ms": per, "differences": diffs, "repeat": repeat}


def _copy_tracker(tracker: Any) -> Any:
    import copy

    return copy.deepcopy(tracker)


# ----------------------------------------------------------------------------- references
def floor_ms(depth: np.ndarray, passes: int, runs: int) -> float:
    """Median ms of ``passes`` float32 read + write passes over a frame-sized array: memory, nothing else."""
    src = np.ascontiguousarray(depth, np.float32)
    dst = np.empty_like(src)
    times = []
    for _ in range(runs):
        t0 = time.thread_time()
        for _ in range(passes):
            np.multiply(src, np.float32(1.0), out=dst)
        times.append((time.thread_time() - t0) * 1e3)
    return statistics.median(times)


def obvious_tool(case: Case, frame: Frame, maps: TerrainMaps, pixels: int) -> dict[str, float]:
    """Open3D normals on the frame's cloud + scikit-fuzzy on the same maps (sampled, scaled to the frame)."""
    import open3d as o3d
    from skfuzzy_oracle import skfuzzy_simulation

    from slzcli.scoring.rules import load_rules
    from slzcli.terrain.geometry import back_project

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    pts = back_project(frame.depth_m, frame.intrinsics).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)].astype(np.float64)
    t0 = time.thread_time()
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(0.15, 30))
    normals_ms = (time.thread_time() - t0) * 1e3

    rules = load_rules(case.config.scoring.fuzzy.rules)
    sim = skfuzzy_simulation(rules)
    inputs = maps.as_dict()
    valid = np.flatnonzero(maps.valid)
    pick = np.random.default_rng(0).choice(valid, size=min(pixels, valid.size), replace=False)
    t0 = time.thread_time()
    for name in rules.input_names:     # arrays: scikit-fuzzy's vectorised use, one call for all the pixels
        sim.input[name] = inputs[name].reshape(-1)[pick].astype(np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.compute()
    per_pixel_ms = (time.thread_time() - t0) * 1e3 / len(pick)
    return {"points": float(len(pts)), "open3d_normals_ms": normals_ms, "skfuzzy_pixels_timed": float(len(pick)),
            "skfuzzy_ms_per_pixel": per_pixel_ms, "skfuzzy_frame_ms": per_pixel_ms * valid.size,
            "total_ms": normals_ms + per_pixel_ms * valid.size}


def profile(core: Core, cases: list[Case], top: int) -> list[dict[str, Any]]:
    """cProfile of one pass over every frame: the ``top`` functions by own time, ms per frame."""
    pr = cProfile.Profile(time.thread_time)
    n = 0
    for case in cases:
        tracker = core.noise.NoiseTracker(case.config.terrain.noise, case.config.terrain.noise_estimate)
        scorer = core.scorer(case.config)
        for frame in case.frames:
            pr.enable()
            run_frame(core, frame, case.config, scorer, tracker)
            pr.disable()
            n += 1
    st = pstats.Stats(pr)
    rows = []
    for (file, line, fn), (_cc, calls, tt, ct, _callers) in st.stats.items():  # type: ignore[attr-defined]
        where = f"{Path(file).name}:{line}({fn})" if line else fn
        rows.append({"function": where, "calls_per_frame": calls / n, "own_ms": tt * 1e3 / n, "cum_ms": ct * 1e3 / n})
    rows.sort(key=lambda r: -r["own_ms"])
    return rows[:top]


# ----------------------------------------------------------------------------- report
def summary(per: list[list[float]]) -> dict[str, float]:
    a = np.asarray(per)
    out = {s: float(np.median(a[:, i])) for i, s in enumerate(STAGES)}
    core = a[:, 1:].sum(axis=1)
    out["maps+score+mask"] = float(np.median(core))
    out["maps+score+mask_max"] = float(core.max())
    out["with_noise"] = float(np.median(a.sum(axis=1)))
    return out


def main() -> None:
    ap = harness.parser(__doc__, "stages")
    ap.add_argument("--before", default="43fd46a", help="git revision of the 'before' code (default: %(default)s)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs per frame and code (after one warm-up)")
    ap.add_argument("--frames", type=int, default=4, help="frames per synth recording")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--skfuzzy-pixels", type=int, default=10000)
    ap.add_argument("--floor-passes", type=int, default=4)
    ap.add_argument("--profile", action="store_true", help="also profile both (cProfile, CPU time)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), help="synth scenes (default: %(default)s)")
    ap.add_argument("--check", action="store_true", help="only the timing table and the differences (no references)")
    args = ap.parse_args()

    cases = synth_cases(args.frames, args.seed, tuple(args.scenes))
    real = realsense_case()
    if real is not None:
        cases.append(real)
    cores = [revision_core(args.before), current_core()]
    results: dict[str, Any] = {
        "cv2_threads": cv2.getNumThreads(), "load_avg_start": os.getloadavg(),
        "before": args.before, "runs": args.runs, "cases": {},
    }
    all_per: dict[str, dict[str, list[list[float]]]] = {c.name: {"cpu": [], "wall": []} for c in cores}
    worst: dict[str, float] = {}
    jitter: dict[str, float] = {}
    for case in cases:
        res = time_case(cores, case, args.runs)
        results["cases"][case.name] = {
            "frames": res["frames"],
            **{c.name: {kind: summary(res["per_frame_ms"][c.name][kind]) for kind in ("cpu", "wall")} for c in cores},
            "max_difference": {k: max(d[k] for d in res["differences"]) for k in res["differences"][0]},
            "max_difference_before_repeated": ({k: max(d[k] for d in res["repeat"]) for k in res["repeat"][0]}
                                               if res["repeat"] else {}),
        }
        for c in cores:
            for kind in ("cpu", "wall"):
                all_per[c.name][kind] += res["per_frame_ms"][c.name][kind]
        for k, v in results["cases"][case.name]["max_difference"].items():
            worst[k] = max(worst.get(k, 0.0), v)
        for k, v in results["cases"][case.name]["max_difference_before_repeated"].items():
            jitter[k] = max(jitter.get(k, 0.0), v)
        b, a = (results["cases"][case.name][n]["cpu"] for n in ("before", "after"))
        print(f"{case.name:<24} {res['frames']:>2} frames  CPU ms before / after: maps {b['maps']:6.1f} / "
              f"{a['maps']:5.1f}  score {b['score']:5.1f} / {a['score']:4.1f}  mask {b['mask']:6.1f} / {a['mask']:5.1f}"
              f"  sum {b['maps+score+mask']:6.1f} / {a['maps+score+mask']:5.1f}  noise {b['noise']:5.1f} / "
              f"{a['noise']:4.1f}", flush=True)
    overall = {c.name: {kind: summary(all_per[c.name][kind]) for kind in ("cpu", "wall")} for c in cores}
    results["all_frames"] = overall
    results["max_difference_all_frames"] = worst
    results["max_difference_before_repeated_all_frames"] = jitter

    diff_line = ("max difference before vs after over all frames: "
                 + ", ".join(f"{k} {v:.3g}" for k, v in worst.items())
                 + "\nthe same, before against itself on the same frame (run-to-run): "
                 + ", ".join(f"{k} {v:.3g}" for k, v in jitter.items()))
    if args.check:
        print(diff_line)
        return
    depth = cases[0].frames[0].depth_m
    floor = floor_ms(depth, args.floor_passes, 50)
    ref_case = next(c for c in cases if c.name.startswith("playground 5"))
    ref_frame = ref_case.frames[0]
    ref_maps = current_core().maps.frame_maps(ref_frame, current_core().map_params(ref_case.config))
    tool = obvious_tool(ref_case, ref_frame, ref_maps, args.skfuzzy_pixels)
    after = overall["after"]["cpu"]["maps+score+mask"]
    before = overall["before"]["cpu"]["maps+score+mask"]
    results["references"] = {
        "paper_ms": PAPER_MS, "obvious_tool": tool, "obvious_tool_frame": f"{ref_case.name}, frame 0",
        f"floor_{args.floor_passes}_passes_ms": floor,
    }
    results["ratios"] = {"paper_over_after": PAPER_MS / after, "paper_over_before": PAPER_MS / before,
                         "before_over_after": before / after, "obvious_tool_over_after": tool["total_ms"] / after,
                         "after_over_floor": after / floor}
    if args.profile:
        results["profile"] = {c.name: profile(c, cases, 25) for c in cores}

    print(f"\nall {len(all_per['after']['cpu'])} frames, one core, median CPU ms per frame (wall in brackets)")
    print(f"  {'stage':<18} {'before':>16} {'after':>16}")
    for k in (*STAGES, "maps+score+mask", "maps+score+mask_max", "with_noise"):
        b, a = overall["before"], overall["after"]
        print(f"  {k:<18} {b['cpu'][k]:>7.1f} ({b['wall'][k]:>6.1f}) {a['cpu'][k]:>7.1f} ({a['wall'][k]:>6.1f})")
    print(f"\n  {'reference':<52} {'ms':>9} {'x slz (after)':>14}")
    print(f"  {'paper (Table 2)':<52} {PAPER_MS:>9.0f} {PAPER_MS / after:>14.1f}")
    print(f"  {'Open3D normals + scikit-fuzzy (' + ref_case.name + ')':<52} {tool['total_ms']:>9.0f} "
          f"{tool['total_ms'] / after:>14.0f}")
    print(f"  {'  of which Open3D estimate_normals':<52} {tool['open3d_normals_ms']:>9.0f}")
    print(f"  {'  of which scikit-fuzzy (scaled from samples)':<52} {tool['skfuzzy_frame_ms']:>9.0f}")
    print(f"  {'slz before (' + args.before + ')':<52} {before:>9.1f} {before / after:>14.2f}")
    print(f"  {'floor: ' + str(args.floor_passes) + ' float32 passes over the depth':<52} {floor:>9.2f} "
          f"{floor / after:>14.3f}")
    print("\n" + diff_line)
    if args.profile:
        for c in cores:
            print(f"\nprofile {c.name} (own CPU ms per frame)")
            for r in results["profile"][c.name][:15]:
                print(f"  {r['own_ms']:7.2f} {r['cum_ms']:7.2f}  {r['function']}")
    harness.write_results(args.out, results)


if __name__ == "__main__":
    main()
