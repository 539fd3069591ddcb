"""Through the CLI: a synth recording whose only flat ground is the top of a 1.8 m box (the ground around it
strewn with rocks): `slz detect` finds no site and says the best one is on a raised surface; with the ground
looked for only on the box itself (``landing.raised.ground_radius_m`` within its top) it lands there, on ground the
truth calls unsafe: the rule is what refuses it."""

from __future__ import annotations

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
    # the annulus within the box top: nothing lower around, the same top becomes the site, truly unsafe
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "b"), *common,
                               "--set", "landing.raised.ground_radius_m=0.7"])
    assert res.exit_code == 0, res.output
    b = json.loads(res.stdout)
    assert b["status"] == "site", b["reason"]
    assert b["ground_truth"]["site"]["safe"] is False
