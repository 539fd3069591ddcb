"""The batch summary of ``slz detect`` over many recordings: ``summary.json`` and ``summary.csv``.

One row per recording (status, site, timings, where it ran); ``summary.json`` adds the batch
totals. Both written atomically, so an interrupted batch leaves the previous pair or the new one.
A later batch into the same folder keeps the earlier batch's rows of the run folders it did not
write (``earlier_rows``): the summary lists every run folder there, the totals this batch's.
The batch folder also holds the run folders (each its own, ``output_dir``) and anything else the
user keeps there; slz writes only these two files in it, and only over a pair it wrote before
(``summary.json`` marked ``slz_output: batch``).
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from slzcli.errors import OutputError, SlzError
from slzcli.outputs import files
from slzcli.outputs.output_dir import MARKER_KEY
from slzcli.outputs.records_json import to_json, to_json_object
from slzcli.records import BatchRow, BatchSettings, BatchTotals

KIND = "batch"

COLUMNS = ("recording", "run", "status", "skipped", "frames", "detections", "site_x", "site_y", "site_z",
           "wall_s", "frames_per_s", "run_wall_s", "per_frame_ms", "worker", "peak_rss_mb", "peak_child_rss_mb",
           "error")


def row_json(row: BatchRow) -> dict[str, object]:
    """A row of ``summary.json`` ``recordings``: a finished run's figures, or the failure (error, detail) and
    whatever of the worker's wall time and memory it measured."""
    out: dict[str, object] = {"recording": row.recording, "run": row.run}
    if row.worker is not None:
        out["worker"] = row.worker
    out.update(status=row.status, skipped=row.skipped)
    s = row.summary
    if s is not None:
        out.update(frames=s.frames, detections=s.detections, site_world=to_json(s.site_world), wall_s=row.wall_s,
                   frames_per_s=row.frames_per_s, run_wall_s=s.wall_s, per_frame_ms=s.timings_ms.get("total"),
                   peak_rss_mb=row.peak_rss_mb, peak_child_rss_mb=row.peak_child_rss_mb, error=None)
        return out
    out["error"] = row.error
    if row.error_detail is not None:
        out["error_detail"] = dict(row.error_detail)
    out.update({k: v for k, v in (("wall_s", row.wall_s), ("peak_rss_mb", row.peak_rss_mb)) if v is not None})
    return out


def csv_rows(rows: Sequence[Mapping[str, object]]) -> list[dict[str, object]]:
    """The CSV view of the batch rows (``row_json``'s): the site split into x, y, z."""
    out = []
    for r in rows:
        site = r.get("site_world")
        if not isinstance(site, list | tuple):
            site = (None, None, None)
        flat = {k: r.get(k) for k in COLUMNS}
        flat.update(site_x=site[0], site_y=site[1], site_z=site[2])
        out.append({k: "" if v is None else v for k, v in flat.items()})
    return out


def check_folder(out_dir: Path) -> None:
    """OutputError unless ``out_dir`` may take a batch summary: missing, or a folder whose summary.json and
    summary.csv (when there) are slz's."""
    out_dir = Path(out_dir)
    if os.path.lexists(out_dir) and not out_dir.is_dir():
        raise OutputError(out_dir, "exists and is not a folder; a batch writes a folder of run folders here: "
                                   "choose another -o")
    json_path, csv_path = out_dir / "summary.json", out_dir / "summary.csv"
    if not os.path.lexists(json_path):
        if os.path.lexists(csv_path):
            raise OutputError(csv_path, "exists and was not written by slz (no summary.json beside it); move it "
                                        "away or choose another -o")
        return
    doc = _read(json_path)
    mark = doc.get(MARKER_KEY) if isinstance(doc, dict) else None
    if isinstance(mark, dict):
        ours = mark.get("kind") == KIND
    else:  # a summary of an slz before the marker had these keys
        ours = isinstance(doc, dict) and {"batch", "recordings"} <= set(doc)
    if not ours:
        raise OutputError(json_path, "exists and is not a batch summary of slz; move it away or choose another -o")


def _read(json_path: Path) -> object:
    """The summary.json document, or None when it cannot be read within the bounds (then it is not slz's)."""
    from slzcli.bounds import load_json

    try:
        return load_json(json_path, "batch summary.json")
    except SlzError:
        return None


def earlier_rows(json_path: Path, new: Sequence[Mapping[str, object]]) -> list[Mapping[str, object]]:
    """The rows of an earlier batch into this folder whose run folders this batch did not write: kept, first.

    A second batch into one folder adds to its summary instead of dropping the first batch's rows;
    a recording run again gets this batch's row only. ``batch`` totals are this batch's alone.
    """
    doc = _read(json_path)
    rows = doc.get("recordings") if isinstance(doc, dict) else None
    if not isinstance(rows, list):
        return []
    now = {r.get("run") for r in new}
    return [r for r in rows if isinstance(r, dict) and r.get("run") not in now]


def write_summary(out_dir: Path, totals: BatchTotals, settings: BatchSettings,
                  rows: Sequence[BatchRow]) -> tuple[Path, Path]:
    """Write ``summary.json`` (batch totals, settings + rows) and ``summary.csv`` (rows) into ``out_dir``."""
    out_dir = Path(out_dir)
    json_path, csv_path = out_dir / "summary.json", out_dir / "summary.csv"
    plain = [row_json(r) for r in rows]
    from slzcli.outputs import run_lock

    with run_lock.claim(json_path, wait=True, leftovers=()):  # two batches ending at once: one merge each
        check_folder(out_dir)  # again: the batch ran for a while
        earlier = earlier_rows(json_path, plain)
        files.write_json(json_path, {MARKER_KEY: {"kind": KIND, "files": ["summary.json", "summary.csv"]},
                                     "batch": {**to_json_object(totals), **to_json_object(settings),
                                               "earlier_rows": len(earlier)},
                                     "recordings": earlier + plain})
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(csv_rows([*earlier, *plain]))
        files.write_text(csv_path, buf.getvalue())
    return json_path, csv_path
