"""What writing a detection frame costs: CPU ms and bytes per detection frame, per writer and per encoding.

    python benchmarks/writes.py [--frames N] [--repeats R] [--set k=v ...]

Renders one small `slz synth` recording (clear_field, gaussian sensor, 640x480 by default) and measures,
in this process:

1. End to end: `slz detect` on it with every frame a detection (``landing.detect_on: every_nth``,
   ``every_nth_frame: 1``), once per variant, the variants interleaved ``--repeats`` times:

   - ``before``: the writer as it was at aed6bd3 (main before this change), re-created by putting its
     pieces back over today's code (``BEFORE`` below): the overlay tinted with a broadcast np.where and
     its dots set through boolean indexing, overlay.png at zlib level 1 with run-length matching,
     float16 through numpy, maps.npz members copied through a BytesIO, results.mcap with raw rgb8
     colour and overlay, the old mono8 and mcap's default zstd chunks;
   - ``level=<L>``: today's writer at each output level (``output.level``).

   Per variant: CPU ms of the write per detection frame (the writer thread's ``time.thread_time`` over
   the overlay, the frame folder and the results.mcap messages: what the write takes from the 2 cores
   however busy the machine is; the median over detection frames), the ``write`` stage's wall ms and
   the loop's wait (run.json), bytes of one ``frames/NNNNNN/`` and of results.mcap per detection frame.
2. Encodings, on one detection frame of that recording (each candidate ``ENCODE_REPEATS`` times, CPU ms
   median, and its bytes): the overlay's drawing and PNG, the colour and overlay in results.mcap, the
   mono8 maps, the float16 casts, maps.npz, and results.mcap's chunk compression with raw or JPEG
   pictures.

Writes benchmarks/results/writes.json.
"""

from __future__ import annotations

import io
import json
import statistics
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np

import slzcli.pipeline as pipeline
from slzcli.config import load_config
from slzcli.outputs import files, images, palette, results_mcap, run_folder
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.pipeline import RunOptions, detect_recording
from slzcli.synth.record import SynthOptions, synthesize

BASE = ("synth.sensor.model=gaussian", "landing.detect_on=every_nth", "landing.every_nth_frame=1",
        "slam.backend=odometry")
ENCODE_REPEATS = 15
MCAP_REPEATS = 7  # results.mcap files per picture format x chunk compression (each with every kept detection)


# ----------------------------------------------------------------------------- the writer before (aed6bd3)
def before_overlay_bgr(rgb: np.ndarray, mask: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    tint = np.where(mask[..., None], images.SAFE_BGR, images.UNSAFE_BGR)
    return cv2.addWeighted(bgr, 1.0 - alpha, tint, alpha, 0.0)


def before_site_overlay_bgr(rgb: np.ndarray, mask: np.ndarray, projected: np.ndarray | None = None,
                            kept: np.ndarray | None = None, chosen: np.ndarray | None = None,
                            corners_px: np.ndarray | None = None) -> np.ndarray:
    img = before_overlay_bgr(rgb, mask)
    h, w = mask.shape
    if projected is not None and len(projected):
        ok = np.all(np.isfinite(projected), axis=1) & (projected[:, 0] >= 0) & (projected[:, 0] < w) \
            & (projected[:, 1] >= 0) & (projected[:, 1] < h)
        layers = [(ok, (255, 255, 255), 1)]
        if kept is not None:
            layers.append((ok & kept, (255, 120, 30), 2))
        if chosen is not None:
            layers.append((ok & chosen, (40, 220, 40), 3))
        for sel, colour, radius in layers:
            dots = np.zeros((h, w), np.uint8)
            pts = np.round(projected[sel]).astype(np.int64)
            dots[np.clip(pts[:, 1], 0, h - 1), np.clip(pts[:, 0], 0, w - 1)] = 1
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
            img[cv2.dilate(dots, disc).astype(bool)] = colour
    if corners_px is not None and np.all(np.isfinite(corners_px)):
        quad = np.round(corners_px[[0, 1, 3, 2]]).astype(np.int32)
        cv2.polylines(img, [quad], True, (0, 0, 255), 2, lineType=cv2.LINE_AA)
    return img


def before_heatmap_bgr(values: np.ndarray, *, reverse: bool = False, valid: np.ndarray | None = None) -> np.ndarray:
    v = np.nan_to_num(values.astype(np.float32), nan=0.0)
    v = np.clip(1.0 - v if reverse else v, 0.0, 1.0)
    img = cv2.applyColorMap((v * 255.0 + 0.5).astype(np.uint8), palette.CV2_COLORMAP)
    img[~np.isfinite(values) if valid is None else ~valid] = 0
    return img


def before_mono8(values: np.ndarray) -> np.ndarray:
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0), 0.0, 1.0)
    return np.rint(v * results_mcap.BYTE_MAX).astype(np.uint8)


def before_npy_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, array: np.ndarray) -> None:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(array, order="C"), allow_pickle=False)
    zf.writestr(info, buf.getvalue())


def before_jpeg(self: Any, name: str, bgr: np.ndarray, stamp: int, camera: str) -> None:
    """results.mcap's pictures as they were: raw rgb8 Images on ``/slz/<name>``."""
    self._image(name, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), "rgb8", stamp, camera)


BEFORE_PNG = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE)
BEFORE_HEAT_PNG = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_DEFAULT)
BEFORE: list[tuple[Any, str, Any]] = [  # (where, name, what it was)
    (images, "overlay_bgr", before_overlay_bgr), (images, "site_overlay_bgr", before_site_overlay_bgr),
    (images, "PHOTO_PNG", BEFORE_PNG), (run_folder, "to_float16", lambda a: np.asarray(a).astype(np.float16)),
    (images, "heatmap_bgr", before_heatmap_bgr), (images, "DEFAULT_PNG", BEFORE_HEAT_PNG),
    (files, "_write_npy_member", before_npy_member), (results_mcap, "mono8", before_mono8),
    (results_mcap.ResultsMcap, "_jpeg", before_jpeg), (results_mcap, "CHUNK_COMPRESSION", "zstd"),
]


@contextmanager
def patched(changes: list[tuple[Any, str, Any]]) -> Iterator[None]:
    old = [(where, name, getattr(where, name)) for where, name, _ in changes]
    for where, name, value in changes:
        setattr(where, name, value)
    try:
        yield
    finally:
        for where, name, value in old:
            setattr(where, name, value)


@contextmanager
def cpu_timed(where: Any, name: str, samples: list[float]) -> Iterator[None]:
    """``where.<name>`` timed in the calling thread's CPU ms into ``samples`` for the block."""
    fn = getattr(where, name)

    def wrapper(*a: Any, **kw: Any) -> Any:
        t0 = time.thread_time()
        try:
            return fn(*a, **kw)
        finally:
            samples.append(1e3 * (time.thread_time() - t0))

    with patched([(where, name, wrapper)]):
        yield


# ----------------------------------------------------------------------------- end to end
def folder_bytes(run: Path) -> list[int]:
    return [sum(f.stat().st_size for f in d.iterdir()) for d in sorted((run / "frames").glob("*"))] \
        if (run / "frames").is_dir() else [0]


def run_variant(rec: Path, out: Path, overrides: list[str], before: bool,
                keep: list[Any] | None = None) -> dict[str, Any]:
    config = load_config(None, [*BASE, *overrides])
    parts: dict[str, list[float]] = {"overlay": [], "frames": [], "results": []}
    t0 = time.perf_counter()
    with ExitStack() as stack:
        if before:
            stack.enter_context(patched(BEFORE))
        stack.enter_context(cpu_timed(pipeline, "detection_overlay_bgr", parts["overlay"]))
        stack.enter_context(cpu_timed(run_folder, "write_detection", parts["frames"]))
        stack.enter_context(cpu_timed(results_mcap.ResultsMcap, "write_detection", parts["results"]))
        if keep is not None:  # a few detections for the encodings, kept from the writer's own calls
            stack.enter_context(patched([(run_folder, "write_detection", keeping(run_folder.write_detection, keep))]))
        s = detect_recording(rec, config, out, RunOptions(force=True))
    wall = time.perf_counter() - t0
    timing = json.loads((out / "run.json").read_text())["timings"]
    n = s.detections
    per_frame = [sum(p[i] for p in parts.values() if len(p) == n) for i in range(n)]
    mcap = out / "results.mcap"
    return {"detections": n, "write_cpu_median_ms": round(statistics.median(per_frame), 2),
            **{f"{k}_cpu_median_ms": round(statistics.median(v), 2) if v else 0.0 for k, v in parts.items()},
            "write_stage_median_ms": round(timing["write"]["median_ms"], 2),
            "write_wait_median_ms": round(timing.get("write_wait", {}).get("median_ms", float("nan")), 2),
            "compute_median_ms": s.timings_ms["total"],
            "bytes_per_frame_folder": int(statistics.median(folder_bytes(out))),
            "results_mcap_bytes_per_detection": int(mcap.stat().st_size / max(n, 1)) if mcap.is_file() else 0,
            "wall_s": round(wall, 3)}


def keeping(fn: Callable[..., Any], keep: list[Any], most: int = 3) -> Callable[..., Any]:
    def wrapper(run_dir: Path, det: Any, *a: Any) -> Any:
        if len(keep) < most:
            keep.append(det)
        return fn(run_dir, det, *a)
    return wrapper


# ----------------------------------------------------------------------------- encodings
def cpu_ms(fn: Callable[[], Any], repeats: int = ENCODE_REPEATS) -> tuple[float, Any]:
    out, samples = None, []
    for _ in range(repeats):
        t0 = time.thread_time()
        out = fn()
        samples.append(1e3 * (time.thread_time() - t0))
    return round(statistics.median(samples), 2), out


def nbytes(x: Any) -> int:
    if isinstance(x, (list, tuple)):
        return sum(nbytes(v) for v in x)
    return int(x.nbytes) if hasattr(x, "nbytes") else len(x)


def encodings(dets: list[Any], tmp: Path) -> dict[str, dict[str, float]]:
    det = dets[len(dets) // 2]
    out: dict[str, dict[str, float]] = {}

    def row(name: str, fn: Callable[[], Any], size: Callable[[Any], int] = nbytes) -> None:
        ms, value = cpu_ms(fn)
        out[name] = {"cpu_ms": ms, "bytes": size(value)}

    def png(img: np.ndarray, params: tuple[int, ...]) -> np.ndarray:
        return cv2.imencode(".png", img, list(params))[1]

    def jpeg(img: np.ndarray) -> np.ndarray:
        return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, results_mcap.JPEG_QUALITY])[1]

    with patched(BEFORE[:2]):
        row("overlay drawn: before (broadcast np.where tint, boolean-indexed dots)", lambda: detection_overlay_bgr(det))
    row("overlay drawn: now (per-channel tint merged, dots by flat index)", lambda: detection_overlay_bgr(det))
    overlay = detection_overlay_bgr(det)
    bgr = cv2.cvtColor(det.frame.rgb, cv2.COLOR_RGB2BGR)
    sub_rle = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
               cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB)
    row("overlay.png: before (zlib 1, run-length, adaptive filters)", lambda: png(overlay, BEFORE_PNG))
    row("overlay.png: zlib 1, run-length, SUB filter", lambda: png(overlay, sub_rle))
    row("overlay.png: now (zlib 0, no filter)", lambda: png(overlay, images.PHOTO_PNG))
    row("mcap colour: raw rgb8 (before; bytes before chunk compression)", lambda: det.frame.rgb.copy())
    row("mcap colour: PNG zlib 1 run-length", lambda: png(bgr, BEFORE_PNG))
    row(f"mcap colour: JPEG q{results_mcap.JPEG_QUALITY} (now)", lambda: jpeg(bgr))
    row(f"mcap overlay: JPEG q{results_mcap.JPEG_QUALITY} (now)", lambda: jpeg(overlay))
    planes = [*det.maps.as_dict().values(), det.score.score]
    row("mcap 5 mono8 maps: before (nan_to_num, clip)", lambda: [before_mono8(v) for v in planes])
    row("mcap 5 mono8 maps: now (fmax/fmin in place)", lambda: [results_mcap.mono8(v) for v in planes])
    bytes8 = [results_mcap.mono8(v) for v in planes]
    row("mcap 5 mono8 maps as PNG (zlib 1, default)", lambda: [png(b, BEFORE_HEAT_PNG) for b in bytes8])
    row("mcap 5 mono8 maps as PNG (zlib 1, run-length, UP)", lambda: [png(b, images.DEFAULT_PNG) for b in bytes8])
    row("mcap 5 mono8 maps as PNG (zlib 1, run-length, SUB)", lambda: [png(b, sub_rle) for b in bytes8])
    heat = [*det.maps.as_dict().values(), det.score.score]
    valid = det.maps.valid
    row("5 heat maps drawn: before (nan_to_num, clip, boolean-indexed black)",
        lambda: [before_heatmap_bgr(v, valid=valid) for v in heat])
    row("5 heat maps drawn: now (fmax/fmin in place, flat-indexed black)",
        lambda: [images.heatmap_bgr(v, valid=valid) for v in heat])
    drawn = [images.with_colour_bar(images.heatmap_bgr(v, valid=valid)) for v in heat]
    row("5 heat-map PNGs: before (zlib 1, default matching, adaptive filters)",
        lambda: [png(h, BEFORE_HEAT_PNG) for h in drawn])
    row("5 heat-map PNGs: now (zlib 1, run-length, UP filter)", lambda: [png(h, images.DEFAULT_PNG) for h in drawn])
    f16 = [v for v in (*det.maps.as_dict().values(), det.maps.slope_deg, det.edge_m) if v is not None]
    row("maps.npz 6 float16 casts: numpy (before)", lambda: [np.asarray(v).astype(np.float16) for v in f16])
    row("maps.npz 6 float16 casts: OpenCV (now)", lambda: [run_folder.to_float16(v) for v in f16])
    arrays = run_folder.detection_arrays(det)
    target = tmp / "enc" / "maps.npz"
    with patched([(files, "_write_npy_member", before_npy_member)]):
        row("maps.npz written: before (through BytesIO)",
            lambda: files.write_npz_streamed(target, arrays, stored=frozenset(arrays)), lambda _: target.stat().st_size)
    row("maps.npz written: now (from the arrays' memory)",
        lambda: files.write_npz_streamed(target, arrays, stored=frozenset(arrays)), lambda _: target.stat().st_size)
    config = load_config(None, [])
    raw = [(results_mcap.ResultsMcap, "_jpeg", before_jpeg)]
    mcap_variants = [(pictures, changes, compression)
                     for pictures, changes in (("raw rgb8 pictures", raw), ("JPEG pictures", []))
                     for compression in ("zstd", "lz4", "none")]
    samples: dict[str, list[float]] = {}
    sizes: dict[str, list[float]] = {}
    for r in range(MCAP_REPEATS):  # interleaved, as the end-to-end variants
        for v, (pictures, changes, compression) in enumerate(mcap_variants):
            name = f"results.mcap per detection: {pictures}, {compression} chunks"
            run = tmp / f"mcap_{v}_{r}"
            run.mkdir(parents=True)
            with patched([*changes, (results_mcap, "CHUNK_COMPRESSION", compression)]), \
                    results_mcap.open_results(run, config) as res:
                res.write_detection(dets[0], overlay)  # schemas and serialisers: not per frame
                t0 = time.thread_time()
                for d in dets:
                    res.write_detection(d, overlay)
                assert isinstance(res, results_mcap.ResultsMcap)
                res.writer.close()  # the last chunk, compressed and written
                samples.setdefault(name, []).append(1e3 * (time.thread_time() - t0) / len(dets))
            sizes.setdefault(name, []).append((run / "results.mcap").stat().st_size / (len(dets) + 1))
    for name in samples:
        out[name] = {"cpu_ms": round(statistics.median(samples[name]), 2), "bytes": int(statistics.median(sizes[name]))}
    return out


# ----------------------------------------------------------------------------- main
def main() -> None:
    ap = harness.parser(__doc__, "writes")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=2, help="runs per variant; the medians of all are kept")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    variants: dict[str, tuple[list[str], bool]] = {"before": ([], True)}
    variants |= {f"level={lv}": ([f"output.level={lv}"], False) for lv in ("summary", "maps", "all")}
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in variants}
    kept: list[Any] = []
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "flight.mcap"
        cfg = load_config(None, [*BASE, *args.overrides])
        synthesize(rec, SynthOptions("clear_field", args.frames, 10.0, "hover", 0, None), cfg)
        for _ in range(args.repeats):  # interleaved: a slow spell of the shared machine hits every variant
            for name, (extra, before) in variants.items():
                rows[name].append(run_variant(rec, Path(tmp) / f"run_{name}", [*args.overrides, *extra], before,
                                              kept if name == "level=maps" and not kept else None))
        enc = encodings(kept, Path(tmp))
    table = {}
    print(f"{'variant':<14} {'det':>4} {'write CPU ms':>12} {'overlay':>8} {'frames/':>8} {'results':>8} "
          f"{'stage ms':>9} {'waited':>7} {'compute ms':>11} {'bytes frames/':>14} {'bytes mcap':>11} {'wall s':>7}")
    for name, runs in rows.items():
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        table[name] = {**med, "runs": runs}
        print(f"{name:<14} {med['detections']:>4.0f} {med['write_cpu_median_ms']:>12.1f} "
              f"{med['overlay_cpu_median_ms']:>8.1f} {med['frames_cpu_median_ms']:>8.1f} "
              f"{med['results_cpu_median_ms']:>8.1f} {med['write_stage_median_ms']:>9.1f} "
              f"{med['write_wait_median_ms']:>7.1f} {med['compute_median_ms']:>11.1f} "
              f"{med['bytes_per_frame_folder']:>14,.0f} {med['results_mcap_bytes_per_detection']:>11,.0f} "
              f"{med['wall_s']:>7.2f}")
    ref = table["before"]["write_cpu_median_ms"]
    for name in table:
        table[name]["write_cpu_vs_before"] = round(table[name]["write_cpu_median_ms"] / ref, 3)
    print(f"\n{'encoding (one 640x480 detection frame)':<82} {'CPU ms':>7} {'bytes':>11}")
    for name, r in enc.items():
        print(f"{name:<82} {r['cpu_ms']:>7.2f} {r['bytes']:>11,}")
    harness.write_results(args.out, {"frames": args.frames, "repeats": args.repeats, "base": list(BASE),
                                     "overrides": args.overrides, "variants": table, "encodings": enc})


if __name__ == "__main__":
    main()
