"""Screenshots of a run's report.html and overlays in headless Chromium, to look at them as a user does.

    python scripts/screenshots.py runs/demo/run -o /tmp/shots [--frame 18] [--chromium chromium]

Writes report.png (the page, 1280 px wide, full height up to --height) and overlay_<frame>.png (the overlay
at its own size in a page), then prints their paths. Not a test: it needs Chromium (apt-get install chromium)
and looks, it does not judge; scripts/ holds such tools, benchmarks/ the measurements.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars"]


def shoot(chromium: str, url: str, out: Path, width: int, height: int) -> Path:
    """One page -> one PNG, in a fresh profile folder (removed afterwards)."""
    with tempfile.TemporaryDirectory(prefix="slz-chromium-") as profile:
        subprocess.run([chromium, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
                        f"--screenshot={out}", url], check=True, capture_output=True, timeout=120)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a run folder of slz detect")
    ap.add_argument("-o", "--output", type=Path, required=True, help="folder for the PNGs")
    ap.add_argument("--frame", type=int, default=None, help="the overlay's frame (default: the committed one)")
    ap.add_argument("--height", type=int, default=4000, help="page height in px (the screenshot's)")
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    args = ap.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    report = (args.run / "report.html").resolve()
    shots = [shoot(args.chromium, report.as_uri(), args.output / "report.png", 1280, args.height)]
    frames = sorted((args.run / "frames").glob("*/overlay.png"))
    if args.frame is not None:
        frames = [p for p in frames if int(p.parent.name) == args.frame]
    else:
        import json

        landing = json.loads((args.run / "landing.json").read_text())
        chosen = (landing.get("frame") or {}).get("index")
        frames = [p for p in frames if chosen is not None and int(p.parent.name) == chosen] or frames[-1:]
    for p in frames[:1]:
        import cv2

        image = cv2.imread(str(p))
        if image is None:
            raise SystemExit(f"{p}: not a readable PNG")
        h, w = image.shape[:2]
        shots.append(shoot(args.chromium, p.resolve().as_uri(), args.output / f"overlay_{p.parent.name}.png",
                           w + 16, h + 16))
    print("\n".join(str(s) for s in shots))
    return 0


if __name__ == "__main__":
    sys.exit(main())
