"""The batch summary of ``slz detect`` over many recordings: ``summary.json`` and ``summary.csv``.

One row per recording (status, site, timings, where it ran); ``summary.json`` adds the batch
totals. Both written atomically, so an interrupted batch leaves the previous pair or the new one.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Sequence

from slzcli.outputs import files

COLUMNS = ("recording", "run", "status", "skipped", "frames", "detections", "site_x", "site_y", "site_z",
           "wall_s", "frames_per_s", "run_wall_s", "per_frame_ms", "worker", "peak_rss_mb", "peak_child_rss_mb", "error")


def csv_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The CSV view of the batch rows: the site split into x, y, z; nested summaries left out."""
    out = []
    for r in rows:
        site = r.get("site_world") or (None, None, None)
        flat = {k: r.get(k) for k in COLUMNS}
        flat.update(site_x=site[0], site_y=site[1], site_z=site[2])
        out.append({k: "" if v is None else v for k, v in flat.items()})
    return out


def write_summary(out_dir: Path, batch: dict[str, Any], rows: Sequence[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``summary.json`` (batch totals + rows) and ``summary.csv`` (rows) into ``out_dir``."""
    out_dir = Path(out_dir)
    json_path, csv_path = out_dir / "summary.json", out_dir / "summary.csv"
    plain = [{k: v for k, v in r.items() if k != "summary"} for r in rows]
    files.write_json(json_path, {"batch": batch, "recordings": plain})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(csv_rows(rows))
    files.write_text(csv_path, buf.getvalue())
    return json_path, csv_path
