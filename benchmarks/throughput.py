"""`slz detect` end to end: frames per second with the stages overlapped against one at a time, and against
the rate ORB-SLAM3 alone allows in the same run.

    python benchmarks/throughput.py [--frames 300] [--repeats 2] [--keep DIR] [--backend orbslam3]
                                    [--size 848x480] [--variants 'NAME;...'] [--set k=v ...]

Renders one `slz synth` descent (parking_lot, 8 m to 3 m, the default D435-like stereo depth,
``--size``, 640x480 by default) of ``--seed-frames`` frames, plays it forwards and backwards to ``--frames`` frames,
then runs the real CLI (`python -m slzcli.cli detect --json`, a fresh process each time:
start-up, vocabulary load and the final write included) in variants interleaved over
``--repeats`` rounds, so that a slow spell of a shared machine hits every variant:

- ``sequential``: one frame at a time, files written in the loop (``slam.track_ahead=false``,
  ``output.write_queue=0``): the reference, measured in the same process as the others;
- ``overlapped``: the defaults (frame n+1 tracked by the SLAM worker while frame n's maps are
  computed; files written by the background writer);
- the same two with every frame a detection (``landing.detect_on=every_nth``,
  ``landing.every_nth_frame=1``);
- ``fused``: the defaults with ``--method fused`` (every tracked frame fused into the world-fixed grid,
  the fused verdict on the detection frames), and ``fused, sequential`` its reference.

Against ORB-SLAM3 alone: per run, the rate its tracking allows (1000 / the median ms per frame of the SLAM
worker's own time, run.json ``timings.slam``, measured in that very run) and the run's end-to-end rate
divided by it (``of_slam_bound``: 1 = slz is as fast as its tracker; the target for ``fused`` is >= 0.7).
That bound counts the tracking thread alone; ORB-SLAM3's LocalMapping and LoopClosing threads share the same
cores. So the same frames are also tracked by ORB-SLAM3 alone (``--slam-alone``, the default: one period of the
ping-pong decoded once into memory and fed again with the recording's stamps, handed to a fresh worker back to
back, as many in its hands as it takes, wall time of the tracking loop, ``--repeats`` times): the rate the tracker
really allows on this machine, and each variant's rate over it (``of_slam_alone``), from the process's wall time
(start-up included) and from the run's own ``wall_s`` (the frame loop and final writes).
The fusion's own cost is run.json ``timings.fuse`` (CPU time of the main thread per tracked frame).

Per variant: median frames/s over the process's wall time, median ms per stage from run.json
(slam is the worker's own time, slam_wait what the main loop waited for it), the ratio
against its sequential reference, and whether the committed site is the same in every run (it
must be: overlapping changes when work is done, not what is computed; ORB-SLAM3 itself is not
bit-reproducible, benchmarks/reproducibility.py). Writes benchmarks/results/throughput.json.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import harness

SEQUENTIAL = ("slam.track_ahead=false", "output.write_queue=0")
EVERY_FRAME = ("landing.detect_on=every_nth", "landing.every_nth_frame=1")
FUSED = ("--method", "fused")
VARIANTS: dict[str, tuple[str, ...]] = {   # --set values, or a CLI option pair
    "sequential": SEQUENTIAL,
    "overlapped": (),
    "every frame, sequential": (*EVERY_FRAME, *SEQUENTIAL),
    "every frame, overlapped": EVERY_FRAME,
    "fused, sequential": (*FUSED, *SEQUENTIAL),
    "fused": FUSED,
}
RATE_HZ = 15.0   # the recording's frame rate (the renderer's, and the ping-pong's)
REFERENCE = {"overlapped": "sequential", "every frame, overlapped": "every frame, sequential",
             "fused": "fused, sequential"}


def render(folder: Path, frames: int, seed_frames: int, size: str = "640x480") -> Path:
    """A ``seed_frames`` descent rendered by `slz synth`, played forwards and backwards to ``frames`` frames at
    15 Hz (tests/long_recording.py: the motion stays continuous, SLAM keeps tracking; rendering 300 stereo frames
    takes the renderer longer than the benchmark itself)."""
    harness.use_test_helpers()
    from long_recording import write_ping_pong

    from slzcli.config import load_config

    tag = "" if size == "640x480" else f"_{size}"
    seed = folder / f"descent_{seed_frames}{tag}.mcap"
    if not seed.exists():
        harness.slz("synth", "parking_lot", "-o", str(seed), "--frames", str(seed_frames), "--rate", f"{RATE_HZ:g}",
                    "--path", "descent", "--start", "0,0,8", *harness.size_overrides(size))
    path = folder / f"descent_{seed_frames}{tag}_x{frames}.mcap"
    if not path.exists():
        write_ping_pong(seed, path, frames, load_config(), rate_hz=RATE_HZ)
    return path


def cli_args(sets: tuple[str, ...]) -> list[str]:
    """``key=value`` items as ``--set key=value``; an ``--option`` and the item after it as they are."""
    out: list[str] = []
    items = iter(sets)
    for s in items:
        out += [s, next(items)] if s.startswith("--") else ["--set", s]
    return out


def run(recording: Path, out: Path, sets: tuple[str, ...]) -> dict[str, Any]:
    cmd = ["detect", str(recording), "-o", str(out), "--json", "--force", *cli_args(sets)]
    t0 = time.perf_counter()
    res = harness.slz(*cmd)
    wall = time.perf_counter() - t0
    summary = json.loads(res.stdout)
    timings = json.loads((out / "run.json").read_text())["timings"]
    landing = json.loads((out / "landing.json").read_text())
    site = landing.get("site", {}).get("center_world")
    fps = summary["frames"] / wall
    slam_ms = timings.get("slam", {}).get("median_ms")
    bound = 1000.0 / slam_ms if slam_ms else None
    fuse = timings.get("fuse")
    return {"frames": summary["frames"], "detections": summary["detections"], "wall_s": round(wall, 3),
            "fps": round(fps, 3), "loop_fps": round(summary["frames"] / summary["wall_s"], 3),
            "status": summary["status"],
            "site": None if site is None else [round(v, 3) for v in site],
            "slam_bound_fps": None if bound is None else round(bound, 2),
            "of_slam_bound": None if bound is None else round(fps / bound, 3),
            "fuse_cpu_ms": None if fuse is None else {k: round(fuse[k], 2) for k in ("median_ms", "mean_ms", "count")},
            "load_1min": round(os.getloadavg()[0], 2),
            "stage_ms": {k: round(v["median_ms"], 2) for k, v in timings.items()}}


def slam_alone(recording: Path, sets: tuple[str, ...], repeats: int, frames_total: int,
               period: int) -> dict[str, Any]:
    """Frames/s of ORB-SLAM3 alone on the recording's frames (decoded first, and the first frame, which starts the
    worker and loads the vocabulary, tracked outside the timing), fed as slz feeds it: as many frames in its
    worker's hands as it takes (``in_flight``), so that it never waits for the next.

    The recording is the ping-pong of ``render``: frame i shows what frame i % ``period`` shows, stamped as
    ``write_ping_pong`` stamps it, so only one period is decoded and held (a 3,000-frame flight would take ~6 GB)."""
    from dataclasses import replace
    from itertools import islice

    from slzcli.config import load_config
    from slzcli.slam.orbslam3 import OrbSlam3Backend
    from slzcli.sources import open_recording

    cfg = load_config(None, [s for s in sets if not s.startswith("--") and "=" in s])
    with open_recording(str(recording), cfg) as rec:
        cycle = list(islice(rec.frames(), period))
    t0 = cycle[0].stamp_ns

    def frame(i: int) -> Any:
        return replace(cycle[i % len(cycle)], index=i, stamp_ns=t0 + round(i * 1e9 / RATE_HZ))

    rates = []
    for _ in range(repeats):
        backend = OrbSlam3Backend(cfg.slam)
        backend.track(frame(0))   # the worker's start (its vocabulary) and the map's first keyframe: not timed
        t_start = time.perf_counter()
        waiting = 0
        for i in range(1, frames_total):
            f = frame(i)
            if waiting == backend.in_flight:
                backend.collect()
                waiting -= 1
            backend.submit(f)
            waiting += 1
        for _ in range(waiting):
            backend.collect()
        rates.append((frames_total - 1) / (time.perf_counter() - t_start))
        backend.close()
    return {"frames": frames_total, "fps": [round(r, 2) for r in rates],
            "fps_median": round(statistics.median(rates), 2)}


def main() -> None:
    ap = harness.parser(__doc__, "throughput")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed-frames", type=int, default=100, help="frames rendered (then played ping-pong)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--backend", default="orbslam3", help="slam.backend of every run")
    ap.add_argument("--keep", type=Path, help="folder for the recording and runs (kept; reused when present)")
    ap.add_argument("--size", default="640x480", help="WxH of the rendered frames")
    ap.add_argument("--variants", default=";".join(VARIANTS), help="a subset of: " + "; ".join(VARIANTS)
                    + " (separated by ';')")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--no-slam-alone", dest="slam_alone", action="store_false",
                    help="skip the ORB-SLAM3-alone reference (only with --backend orbslam3)")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="slz_throughput_"))
    work.mkdir(parents=True, exist_ok=True)
    recording = render(work, args.frames, args.seed_frames, args.size)
    variants = {k.strip(): VARIANTS[k.strip()] for k in args.variants.split(";")}
    base = (f"slam.backend={args.backend}", *args.overrides)
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in variants}
    alone: list[float] = []
    for _ in range(args.repeats):
        if args.slam_alone and args.backend == "orbslam3":   # interleaved with the variants, like them
            alone += slam_alone(recording, base, 1, args.frames, 2 * args.seed_frames - 2)["fps"]
        for name, sets in variants.items():
            rows[name].append(run(recording, work / f"run_{name.replace(', ', '_').replace(' ', '_')}",
                                  (*base, *sets)))
    table: dict[str, Any] = {}
    alone_fps = statistics.median(alone) if alone else None
    if alone_fps:
        print(f"ORB-SLAM3 alone: {alone_fps:.2f} frames/s (median of {', '.join(f'{a:.2f}' for a in alone)})")
    print(f"{'variant':<26} {'frames':>6} {'det':>4} {'frames/s':>8} {'x ref':>6} {'x slam':>6} {'x alone':>7} "
          f"{'loop':>6} {'slam':>6} {'wait':>6} {'maps':>6} {'fuse':>6} {'write':>6} {'waited':>6}  site")
    for name, runs in rows.items():
        fps = statistics.median(r["fps"] for r in runs)
        stages = {k: statistics.median(r["stage_ms"].get(k, float("nan")) for r in runs)
                  for k in runs[0]["stage_ms"]}
        sites = {json.dumps(r["site"]) for r in runs}
        of_slam = [r["of_slam_bound"] for r in runs if r["of_slam_bound"] is not None]
        loop = statistics.median(r["loop_fps"] for r in runs)
        table[name] = {"fps_median": round(fps, 3), "loop_fps_median": round(loop, 3),
                       "of_slam_alone": round(fps / alone_fps, 3) if alone_fps else None,
                       "loop_of_slam_alone": round(loop / alone_fps, 3) if alone_fps else None,
                       "stage_ms_median": stages, "runs": runs,
                       "of_slam_bound_median": round(statistics.median(of_slam), 3) if of_slam else None,
                       "same_site_every_run": len(sites) == 1}
        ref = REFERENCE.get(name)
        ratio = fps / table[ref]["fps_median"] if ref and ref in table else 1.0
        table[name]["ratio_to_reference"] = round(ratio, 3)
        nan = float("nan")
        print(f"{name:<26} {runs[0]['frames']:>6} {runs[0]['detections']:>4} {fps:>8.2f} {ratio:>6.2f} "
              f"{table[name]['of_slam_bound_median'] or nan:>6.2f} {table[name]['of_slam_alone'] or nan:>7.2f} "
              f"{loop:>6.2f} "
              f"{stages.get('slam', nan):>6.1f} {stages.get('slam_wait', nan):>6.1f} "
              f"{stages.get('maps', nan):>6.1f} {stages.get('fuse', nan):>6.1f} {stages.get('write', nan):>6.1f} "
              f"{stages.get('write_wait', float('nan')):>6.1f}  {runs[0]['site']}")
    harness.write_results(args.out, {"frames": args.frames, "repeats": args.repeats, "base": list(base),
                                     "size": args.size, "slam_alone_fps": alone, "slam_alone_fps_median": alone_fps,
                                     "variants": table})


if __name__ == "__main__":
    main()
