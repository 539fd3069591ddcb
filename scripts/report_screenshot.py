"""Check that `slz compare`'s report.html renders: headless Chromium screenshot, then simple pixel checks.

Not part of the pytest suite (CI has no Chromium). Usage:

    .venv/bin/python scripts/report_screenshot.py [REPORT.html] [--png /tmp/report.png]

Without REPORT, renders a small parking_lot recording (12 frames), runs `slz compare` on it in
a temporary folder and screenshots that report. Prints a table and writes
benchmarks/results/report_screenshot.json. Look at the PNG yourself: the checks only catch a
blank or broken page, not a wrong one. Skips (exit 0, message) when Chromium is absent.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SLZ = REPO / ".venv" / "bin" / "slz"
WINDOW = (1280, 2000)       # px; the window the issue asks for
BLANK_STD = 5.0             # grey levels; a page whose pixels vary less than this is blank
MIN_INK_FRACTION = 0.02     # share of non-white pixels a rendered report must have at least


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def make_report(work: Path) -> Path:
    rec = work / "parking_lot.mcap"
    subprocess.run([str(SLZ), "synth", "parking_lot", "-o", str(rec), "--frames", "12"], check=True,
                   stdout=subprocess.DEVNULL)
    subprocess.run([str(SLZ), "compare", str(rec), "-o", str(work / "compare")], check=True, stdout=subprocess.DEVNULL)
    return work / "compare" / "report.html"


def screenshot(browser: str, report: Path, png: Path) -> float:
    profile = tempfile.mkdtemp(prefix="slz-chromium-")
    t0 = time.perf_counter()
    try:
        subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                        "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                        f"--screenshot={png}", f"--window-size={WINDOW[0]},{WINDOW[1]}", report.resolve().as_uri()],
                       check=True, capture_output=True, timeout=120)
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", nargs="?", type=Path)
    ap.add_argument("--png", type=Path, default=Path("/tmp/report.png"))
    args = ap.parse_args()
    browser = chromium()
    if browser is None:
        print("skipped: no chromium on PATH (apt-get install -y chromium)")
        return 0
    with tempfile.TemporaryDirectory(prefix="slz-report-") as tmp:
        report = args.report or make_report(Path(tmp))
        html_bytes = report.stat().st_size
        images = report.read_text().count("<img ")
        seconds = screenshot(browser, report, args.png)
    img = cv2.imread(str(args.png), cv2.IMREAD_GRAYSCALE)
    if img is None:
        print(f"FAILED: chromium wrote no readable screenshot at {args.png}")
        return 1
    std = float(img.std())
    ink = float((img < 200).mean())
    ok = img.shape[::-1] == WINDOW and std > BLANK_STD and ink > MIN_INK_FRACTION and images > 0
    result = {"report": str(report) if args.report else "generated (parking_lot, 12 frames)", "html_bytes": html_bytes,
              "images_inline": images, "screenshot": str(args.png), "size_px": list(img.shape[::-1]),
              "grey_std": round(std, 2), "ink_fraction": round(ink, 4), "render_s": round(seconds, 2), "ok": ok,
              "chromium": subprocess.run([browser, "--version"], capture_output=True, text=True).stdout.strip()}
    rows = [(k, str(v)) for k, v in result.items()]
    width = max(len(k) for k, _ in rows)
    print("\n".join(f"{k:<{width}}  {v}" for k, v in rows))
    out = REPO / "benchmarks" / "results" / "report_screenshot.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
