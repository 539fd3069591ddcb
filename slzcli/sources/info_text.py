"""The human text of ``slz info``: plain aligned columns (readable in a terminal, a pipe or a log)."""

from __future__ import annotations

from collections.abc import Sequence

from slzcli.sources.depth_check import PERCENTILES, DepthRange
from slzcli.sources.recording import RecordingInfo


def _table(rows: Sequence[tuple[str, ...]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(c.ljust(w) if i < len(r) - 1 else c
                             for i, (c, w) in enumerate(zip(r, widths, strict=True))).rstrip()
            for r in rows]


def depth_text(d: DepthRange) -> list[str]:
    """The depth stream's range over the frames read (the warning is printed by the log)."""
    if d.unread:
        return [f"depth ({d.stream}): not read ({d.unread})"]
    pct = "  ".join(f"p{p} {v:.3f} m" for p, v in zip(PERCENTILES, d.percentiles_m, strict=True))
    return [f"depth ({d.stream}, {d.frames} frame(s) read):",
            f"  {pct}  valid {d.valid_share:.0%}  nearer than {d.min_range_m:g} m ({d.min_range_source}) "
            f"{d.below_min_share:.0%}"]


def info_text(info: RecordingInfo, depth: DepthRange | None = None) -> str:
    """Several lines: header, topic table, chosen streams with reasons, intrinsics, pairing, the depth's range."""
    lines = [f"{info.path}", f"  format: {info.format}   duration: {info.duration_s:.3f} s", "", "topics:"]
    rows = [("topic", "type", "count", "rate")]
    for s in info.streams:
        rate = f"{s.rate_hz:.2f} Hz" if s.rate_hz is not None else "-"
        rows.append((s.topic, s.msgtype, str(s.count), rate))
    lines += _table(rows)
    lines += ["", f"camera preset: {info.camera_preset or '(none)'}"
                  + (f"  ({info.camera_preset_reason})" if info.camera_preset_reason else "")]
    lines += ["", "streams slz uses:"]
    lines += _table([(c.role, c.topic or "(none)", c.reason) for c in info.choices])
    k = info.intrinsics
    lines += ["", f"intrinsics ({info.intrinsics_source}):"]
    if k is not None:
        lines.append(f"  {k.width}x{k.height}  fx {k.fx:.3f}  fy {k.fy:.3f}  cx {k.cx:.3f}  cy {k.cy:.3f}"
                     + (f"  {k.distortion_model} {list(k.distortion)}" if k.distortion_model else ""))
    if info.depth_to_color:
        lines.append(f"  depth: {info.depth_to_color}")
    p = info.pairing
    lines += ["", f"RGB-D frames that pair: {p.paired}  (unpaired colour {p.unpaired_color}, "
                  f"unpaired depth {p.unpaired_depth}, unreadable {p.undecodable})"]
    lines += [f"  note: {n}" for n in p.notes]
    if depth is not None:
        lines += ["", *depth_text(depth)]
    lines += [f"warning: {w}" for w in info.warnings if w not in p.notes]
    return "\n".join(lines)
