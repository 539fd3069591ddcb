"""The batch summary of ``slz detect`` over many recordings: ``summary.json`` and ``summary.csv``.

One row per recording (status, site, timings, where it ran); ``summary.json`` adds the batch
totals. Both written atomically, so an interrupted batch leaves the previous pair or the new one.
The batch folder also holds the run folders (each its own, ``output_dir``) and anything else the
user keeps there; slz writes only these two files in it, and only over a pair it wrote before
(``summary.json`` marked ``slz_output: batch``).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from slzcli.errors import OutputError
from slzcli.outputs import files
from slzcli.outputs.output_dir import MARKER_KEY

KIND = "batch"

COLUMNS = ("recording", "run", "status", "skipped", "frames", "detections", "site_x", "site_y", "site_z",
           "wall_s", "frames_per_s", "run_wall_s", "per_frame_ms", "worker", "peak_rss_mb", "peak_child_rss_mb",
           "error")


def csv_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The CSV view of the batch rows: the site split into x, y, z; nested summaries left out."""
    out = []
    for r in rows:
        site = r.get("site_world") or (None, None, None)
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
    try:
        doc = json.loads(json_path.read_text())
    except (OSError, ValueError):
        doc = None
    mark = doc.get(MARKER_KEY) if isinstance(doc, dict) else None
    if isinstance(mark, dict):
        ours = mark.get("kind") == KIND
    else:  # a summary of an slz before the marker had these keys
        ours = isinstance(doc, dict) and {"batch", "recordings"} <= set(doc)
    if not ours:
        raise OutputError(json_path, "exists and is not a batch summary of slz; move it away or choose another -o")


def write_summary(out_dir: Path, batch: dict[str, Any], rows: Sequence[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``summary.json`` (batch totals + rows) and ``summary.csv`` (rows) into ``out_dir``."""
    out_dir = Path(out_dir)
    json_path, csv_path = out_dir / "summary.json", out_dir / "summary.csv"
    plain = [{k: v for k, v in r.items() if k != "summary"} for r in rows]
    check_folder(out_dir)  # again: the batch ran for a while
    files.write_json(json_path, {MARKER_KEY: {"kind": KIND, "files": ["summary.json", "summary.csv"]},
                                 "batch": batch, "recordings": plain})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(csv_rows(rows))
    files.write_text(csv_path, buf.getvalue())
    return json_path, csv_path
