"""Same bytes: `slz detect` of the current code against the code of a reference commit, file by file.

Run: .venv/bin/python benchmarks/same_bytes.py [--ref REV] [--runs 2] [--frames 4] [--scenes parking_lot,office]
[--out F]. Prints a table and writes benchmarks/results/same_bytes.json; exits 1 when any file differs.

A refactoring of the run machinery must not change a result. Both codes detect on the same small
synth recordings (gaussian sensor, half the default camera, as the tests render them; rendered once by
the current code) on the deterministic backends (odometry, recorded poses) for every method of the
reference code, and landing.json, sites.csv and every frames/*/maps.npz must be byte-identical.
The current code runs ``--runs`` times per case and must give the same bytes every time (``unstable``
lists what did not): a result that depends on the run is a defect of its own, and it would make the
comparison noisy. Left out, because it differs from run to run: landing.json's ``timings_ms``
(wall-clock medians). A file that differs from the reference is checked against a second run of the
reference code: when that differs too, the file is reported as unstable in the reference, not as a
change (an older reference can be: while the normals' norm was OpenCV's IPP ``magnitude``, which rounds
by the arrays' addresses, the slope and score of a few pixels moved from run to run). A maps.npz that
differs says which members, at how many pixels and by how much. Nothing else is left out: the
recording path is the same for both, maps.npz members carry a fixed zip date. New landing.json keys a
change adds on purpose (``DECLARED``) are left out too and printed as the declared differences. ``--ref`` defaults to
the merge base with main.
"""

from __future__ import annotations

import csv
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from harness import git, parser, reference_checkout, slz, write_results

METHODS = ("fuzzy", "bayes", "px4slp")
BACKENDS = {"odometry": ("--set", "slam.backend=odometry"),
            "recorded": ("--set", "slam.backend=recorded", "--set", "sources.use_ground_truth_pose=true")}
GAUSSIAN = ("--set", "synth.sensor.model=gaussian")
HALF_SIZE = ("--set", "camera.width=320", "--set", "camera.height=240", "--set", "camera.fx=231.0685",
             "--set", "camera.fy=231.0685", "--set", "camera.cx=160", "--set", "camera.cy=120")
RUN_SPECIFIC = {"landing.json": ("timings_ms",)}  # top-level keys that differ between two runs of the same code
# New landing.json keys and sites.csv columns a change adds on purpose (declared, documented): removed from both
# runs' files before comparing, and reported beside the result. advice: what would decide the ground
# (records.DecideAdvice); raised_m, raised_cells: the raised-surface rule's reading per cluster (types.Candidate).
DECLARED = {"landing.json": ("advice",), "sites.csv": ("raised_m", "raised_cells")}


def npz_differ(a: bytes, b: bytes) -> str | None:
    """Why two maps.npz differ (None: the same bytes): each member that differs, where and by how much."""
    if a == b:
        return None
    with np.load(io.BytesIO(a)) as za, np.load(io.BytesIO(b)) as zb:
        if sorted(za.files) != sorted(zb.files):
            return f"members {sorted(za.files)} != {sorted(zb.files)}"
        why = []
        for name in za.files:
            x, y = za[name], zb[name]
            if x.dtype != y.dtype or x.shape != y.shape:
                why.append(f"{name}: {x.dtype}{x.shape} != {y.dtype}{y.shape}")
            elif x.tobytes() != y.tobytes():
                why.append(f"{name} {_member_differ(x, y)}")
    return "; ".join(why) or "zip bytes differ"


def _member_differ(x: np.ndarray, y: np.ndarray) -> str:
    """Where one maps.npz member differs: pixels and, for floats, the largest difference and in float16 steps."""
    if x.dtype.kind != "f":
        return f"differs at {int(np.count_nonzero(x != y))} px"
    both_nan = np.isnan(x) & np.isnan(y)
    px = int(np.count_nonzero((x != y) & ~both_nan))
    gap = np.abs(x.astype(np.float64) - y.astype(np.float64))[~both_nan]
    big = float(np.nanmax(gap)) if gap.size else 0.0
    if x.dtype == np.float16:
        steps = np.abs(x.view(np.int16).astype(np.int32) - y.view(np.int16).astype(np.int32))[~both_nan]
        return f"differs at {px} px by <= {big:.3g} ({int(steps.max())} float16 steps)"
    return f"differs at {px} px by <= {big:.3g}"


def comparable(run: Path) -> dict[str, bytes]:
    """The files compared, by name, with their run-specific fields removed."""
    out: dict[str, bytes] = {}
    landing = json.loads((run / "landing.json").read_text())
    for key in (*RUN_SPECIFIC["landing.json"], *DECLARED["landing.json"]):
        landing.pop(key, None)
    out["landing.json"] = json.dumps(landing, sort_keys=True).encode()
    out["sites.csv"] = _without_columns((run / "sites.csv").read_text(), DECLARED["sites.csv"]).encode()
    for p in sorted(run.glob("frames/*/maps.npz")):
        out[str(p.relative_to(run))] = p.read_bytes()
    return out


def _without_columns(text: str, names: tuple[str, ...]) -> str:
    """A csv's text without the named columns, written back as site_log writes it."""
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return text
    keep = [i for i, name in enumerate(rows[0]) if name not in names]
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows([row[i] for i in keep] for row in rows)
    return buf.getvalue()


def difference(name: str, a: bytes | None, b: bytes | None) -> str | None:
    """Why file ``name`` differs between the two runs (None: the same)."""
    if a is None or b is None:
        return "written by one run only"
    if name.endswith(".npz"):
        return npz_differ(a, b)
    if name.endswith(".json") and a != b:
        x, y = json.loads(a), json.loads(b)
        return "differs at " + ", ".join(_json_paths(x, y)[:4])
    return None if a == b else "bytes differ"


def _json_paths(x: object, y: object, at: str = "") -> list[str]:
    """The paths at which two JSON values differ."""
    if isinstance(x, dict) and isinstance(y, dict):
        return [p for k in sorted(x.keys() | y.keys()) for p in _json_paths(x.get(k), y.get(k), f"{at}.{k}")]
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        return [p for i, (u, v) in enumerate(zip(x, y, strict=True)) for p in _json_paths(u, v, f"{at}[{i}]")]
    return [] if x == y else [at or "."]


def detect(code: Path, rec: Path, out: Path, method: str, backend: str) -> dict[str, bytes]:
    slz("detect", str(rec), "-o", str(out), "--method", method, *BACKENDS[backend], "--set", "output.level=maps",
        "--set", "output.results_mcap=false", code=code)
    return comparable(out)


def main() -> None:
    ap = parser(__doc__, "same_bytes")
    ap.add_argument("--ref", default=None, help="reference commit (default: git merge-base HEAD main)")
    ap.add_argument("--runs", type=int, default=2, help="runs of the current code per case (>= 2 checks it is stable)")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--scenes", default="parking_lot,office")
    args = ap.parse_args()
    ref = args.ref or git("merge-base", "HEAD", "main")
    rows = []
    with tempfile.TemporaryDirectory(prefix="slz-same-") as tmp, reference_checkout(ref) as old:
        work = Path(tmp)
        for scene in args.scenes.split(","):
            rec = work / f"{scene}.mcap"
            slz("synth", scene, "-o", str(rec), "--frames", str(args.frames), *GAUSSIAN, *HALF_SIZE)
            for backend in BACKENDS:
                for method in METHODS:
                    tag = f"{scene}-{backend}-{method}"
                    before = detect(old, rec, work / "old" / tag, method, backend)
                    afters = [detect(Path(__file__).resolve().parent.parent, rec, work / f"new{i}" / tag, method,
                                     backend) for i in range(max(1, args.runs))]
                    after = afters[0]
                    unstable = sorted({f"{k} ({why})" for again in afters[1:] for k in after.keys() | again.keys()
                                       if (why := difference(k, after.get(k), again.get(k)))})
                    differ = sorted(f"{k} ({why})" for k in before.keys() | after.keys()
                                    if (why := difference(k, before.get(k), after.get(k))))
                    if differ:  # the reference again: a file it does not reproduce itself is not the change's
                        again = detect(old, rec, work / "old2" / tag, method, backend)
                        differ = [d if difference(d.split(" ")[0], before.get(d.split(" ")[0]),
                                                  again.get(d.split(" ")[0])) is None
                                  else f"{d}, unstable: the reference differs from itself" for d in differ]
                    rows.append({"scene": scene, "backend": backend, "method": method, "files": len(before),
                                 "differ": differ, "runs": len(afters), "unstable": unstable})
                    shaky = f"; UNSTABLE over {len(afters)} runs: {', '.join(unstable)}" if unstable else ""
                    print(f"{scene:<12} {backend:<9} {method:<7} {len(before):>3} files  "
                          f"{'same' if not differ else 'DIFFER: ' + ', '.join(differ)}{shaky}", flush=True)
    same = all(d.endswith("differs from itself") for r in rows for d in r["differ"]) and not any(
        r["unstable"] for r in rows)
    write_results(args.out, {"reference": ref, "head": git("rev-parse", "HEAD"), "frames": args.frames,
                             "runs": args.runs,
                             "left_out": RUN_SPECIFIC, "declared": DECLARED, "rows": rows, "all_same": same})
    print("declared differences (new keys, left out of the comparison): "
          + "; ".join(f"{name}: {', '.join(keys)}" for name, keys in DECLARED.items()))
    sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
