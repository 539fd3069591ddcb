"""What writing a detection frame costs: ms per frame and bytes per frame folder, per output variant.

    python benchmarks/writes.py [--frames N] [--repeats R] [--set k=v ...]

Renders one small `slz synth` recording (clear_field, gaussian sensor, 640x480 by default) and
runs `slz detect` on it in this process with every frame a detection (``landing.detect_on:
every_nth``, ``every_nth_frame: 1``), once per variant:

- ``before``: the writer as it was (PNGs at OpenCV's default zlib level 3, maps.npz deflated,
  written in the main loop), re-created here so both are measured in the same process;
- ``level=<L>``: today's writer at each output level (``output.level``).

Per variant: median ms of the ``write`` stage (``run.json`` timings: the run folder's frame
files plus that frame's results.mcap messages; with the background writer, the time the main
loop waited), median ms of the frame-folder writer itself, median bytes of one
``frames/NNNNNN/`` folder, and the run's wall time. Writes benchmarks/results/writes.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2

from slzcli.config import load_config
from slzcli.outputs import files, images, run_folder
from slzcli.pipeline import RunOptions, detect_recording
from slzcli.synth.record import SynthOptions, synthesize

HERE = Path(__file__).resolve().parent
BASE = ("synth.sensor.model=gaussian", "landing.detect_on=every_nth", "landing.every_nth_frame=1",
        "slam.backend=odometry")


def legacy_write_detection(run_dir: Path, det: Any, config: Any, *_overlay: Any) -> None:
    """The frame writer before the output level: 7 PNGs at zlib level 3 and a deflated maps.npz (it draws its own
    overlay, as it did)."""
    folder = run_dir / "frames" / f"{det.frame.index:06d}"
    reverse, valid = config.output.reverse_colormap, det.maps.valid

    def png(path: Path, image: Any) -> None:
        ok, buf = cv2.imencode(".png", image)  # OpenCV's default: zlib level 3
        assert ok
        files.write_bytes(path, buf.tobytes())

    for name, values in det.maps.as_dict().items():
        png(folder / f"{name}.png", images.heatmap_bgr(values, reverse=reverse, valid=valid))
    png(folder / "score.png", images.heatmap_bgr(det.score.score, reverse=reverse, valid=valid))
    png(folder / "mask.png", images.mask_png(det.score.mask))
    png(folder / "overlay.png", run_folder.detection_overlay_bgr(det))
    arrays = dict(score=det.score.score, mask=det.score.mask, valid=valid, slope_deg=det.maps.slope_deg,
                  edge_distance_m=det.edge_m, **det.maps.as_dict())
    files.write_npz_streamed(folder / "maps.npz", dict(arrays))  # every member deflated


@contextmanager
def timed(name: str, fn: Callable[..., Any], samples: list[float]) -> Iterator[None]:
    """Replace ``run_folder.<name>`` by ``fn`` timed into ``samples`` (ms) for the block."""
    old = getattr(run_folder, name)

    def wrapper(*a: Any, **kw: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*a, **kw)
        finally:
            samples.append(1e3 * (time.perf_counter() - t0))

    setattr(run_folder, name, wrapper)
    try:
        yield
    finally:
        setattr(run_folder, name, old)


def folder_bytes(run: Path) -> list[int]:
    return [sum(f.stat().st_size for f in d.iterdir()) for d in sorted((run / "frames").glob("*"))] \
        if (run / "frames").is_dir() else [0]


def run_variant(rec: Path, out: Path, overrides: list[str], legacy: bool) -> dict[str, Any]:
    config = load_config(None, [*BASE, *overrides])
    writer_ms: list[float] = []
    fn = legacy_write_detection if legacy else run_folder.write_detection
    t0 = time.perf_counter()
    with timed("write_detection", fn, writer_ms):
        s = detect_recording(rec, config, out, RunOptions(force=True))
    wall = time.perf_counter() - t0
    timing = json.loads((out / "run.json").read_text())["timings"]
    sizes = folder_bytes(out)
    return {"detections": s["detections"], "write_stage_median_ms": round(timing["write"]["median_ms"], 2),
            "write_wait_median_ms": round(timing.get("write_wait", {}).get("median_ms", float("nan")), 2),
            "frame_writer_median_ms": round(statistics.median(writer_ms), 2),
            "compute_median_ms": s["timings_ms"]["total"],
            "bytes_per_frame_folder": int(statistics.median(sizes)), "wall_s": round(wall, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=2, help="runs per variant; the medians of all are kept")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "writes.json")
    args = ap.parse_args()
    variants: dict[str, tuple[list[str], bool]] = {"before": ([], True)}
    if "level" in getattr(load_config(None, []).output, "__dataclass_fields__", {}):
        variants |= {f"level={lv}": ([f"output.level={lv}"], False) for lv in ("summary", "maps", "all")}
    else:
        variants["today"] = ([], False)
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in variants}
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "flight.mcap"
        cfg = load_config(None, [*BASE, *args.overrides])
        synthesize(rec, SynthOptions("clear_field", args.frames, 10.0, "hover", 0, None), cfg)
        for _ in range(args.repeats):  # interleaved: a slow spell of the shared machine hits every variant
            for name, (extra, legacy) in variants.items():
                rows[name].append(run_variant(rec, Path(tmp) / f"run_{name}", [*args.overrides, *extra], legacy))
    table = {}
    print(f"{'variant':<14} {'det':>4} {'write ms':>9} {'waited ms':>9} {'writer ms':>10} {'compute ms':>11} "
          f"{'write/compute':>13} {'bytes/frame':>12} {'wall s':>7}")
    for name, runs in rows.items():
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        table[name] = {**med, "runs": runs}
        ratio = med["write_stage_median_ms"] / med["compute_median_ms"]
        table[name]["write_over_compute"] = round(ratio, 3)
        print(f"{name:<14} {med['detections']:>4.0f} {med['write_stage_median_ms']:>9.1f} "
              f"{med['write_wait_median_ms']:>9.1f} {med['frame_writer_median_ms']:>10.1f} "
              f"{med['compute_median_ms']:>11.1f} {ratio:>13.2f} "
              f"{med['bytes_per_frame_folder']:>12,.0f} {med['wall_s']:>7.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"frames": args.frames, "repeats": args.repeats, "base": list(BASE),
                                    "overrides": args.overrides, "variants": table}, indent=2) + "\n")


if __name__ == "__main__":
    main()
