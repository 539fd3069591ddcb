"""Through the CLI: a synth recording whose only flat ground is the top of a 1.8 m box (the ground around it
strewn with rocks): `slz detect` finds no site and says the best one is on a raised surface (sites.csv: the
height it measured); with the ground looked for only within 0.65 m (``landing.raised.ground_radius_m``: too few cells
around the site to measure) it lands there, on ground the truth calls unsafe, and the site's acceptance reason and
sites.csv say the rule was not measured: the rule is what refuses it, and an unmeasured rule is never silent."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

from conftest import GAUSSIAN, HALF_SIZE

from slzcli.cli import main
from slzcli.synth.scenes import SCENES_DIR

SCENE = """description: "A 3.4 x 3.0 m concrete box 1.8 m high under the start, on ground strewn with rocks."
scenario: 3
ground: {size_m: [30, 30], center_m: [0, 0], material: dirt}
objects:
  - {name: rock, kind: box, at_m: [-6.0, -6.0], size_m: [0.35, 0.35, 0.3], material: rock,
     repeat: {count: [16, 16], pitch_m: [0.8, 0.8]}}
  - {name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, 1.8], material: concrete}
"""


def test_detect_refuses_a_raised_box_top_and_says_so(tmp_path: Path, runner) -> None:
    scene = tmp_path / "raised_box.yaml"
    scene.write_text(SCENE)
    shutil.copy(SCENES_DIR / "_common.yaml", tmp_path / "_common.yaml")   # the shared materials
    rec = tmp_path / "box.mcap"
    res = runner.invoke(main, ["synth", str(scene), "-o", str(rec), "--frames", "10", "--path", "hover",
                               "--start", "0,0,5.5", *GAUSSIAN, *HALF_SIZE])
    assert res.exit_code == 0, res.output
    common = ["--json", "--method", "fuzzy", "--set", "landing.kmeans_k=1", *HALF_SIZE]   # the top as one cluster
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "a"), *common])
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    assert s["status"] == "no_safe_site", s
    # 1.8 m less the rocks (0.3 m high, a fifth of the ground) that the lowest third of the annulus takes in
    assert re.match(r"the best site is on a surface 1\.[4-9] m above the ground around it", s["reason"]), s["reason"]
    run = json.loads((tmp_path / "a" / "run.json").read_text())
    assert run["funnel"]["clusters_failed"].get("raised", 0) >= 1
    with open(tmp_path / "a" / "sites.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    refused = [r for r in rows if r["reason"].startswith("on a surface")]
    assert refused and all(1.4 <= float(r["raised_m"]) <= 1.9 and int(r["raised_cells"]) >= 20 for r in refused)
    # the annulus 0.61-0.65 m: too few cells to measure, the same top becomes the site, truly unsafe, with a note
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "b"), *common,
                               "--set", "landing.raised.ground_radius_m=0.65"])
    assert res.exit_code == 0, res.output
    b = json.loads(res.stdout)
    assert b["status"] == "site", b["reason"]
    assert b["ground_truth"]["site"]["safe"] is False
    reason = json.loads((tmp_path / "b" / "landing.json").read_text())["site"]["acceptance"]["reason"]
    assert re.search(r"raised-surface rule not measured: \d+ cells around it with depth, fewer than "
                     r"landing\.raised\.min_cells 20", reason), reason
    with open(tmp_path / "b" / "sites.csv", newline="") as fh:
        chosen = [r for r in csv.DictReader(fh) if r["chosen"] == "True"]
    assert chosen and all(r["raised_m"] == "" and int(r["raised_cells"]) < 20 for r in chosen), chosen
