"""What commands print: whole sentences, rounded figures, the site's height said so it cannot read as underground."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner

from slzcli.cli import main
from slzcli.landing.height import site_height
from slzcli.outputs.report import TABLE_HEAD, without_empty_truth
from slzcli.records import SiteHeight
from slzcli.render import height_text, simulate_text


def test_site_height_above_ground_and_start_with_frames() -> None:
    map_z = np.array([-8.1, -8.0, -8.0, -7.9, -6.5])  # ground at -8 m, a car roof
    h = site_height([1.0, 2.0, -7.98], map_z, "map", 0)
    assert h["above_start_m"] == -7.98 and h["above_ground_m"] == 0.02 and h["ground_z_m"] == -8.0
    assert h["frame_id"] == "map" and h["start_frame"] == 0 and "5 SLAM map points" in h["ground"]
    assert height_text(SiteHeight(**h)) == ("0.02 m above the ground, 7.98 m below the start (frame 0's camera, "
                                            "map frame map)")
    recorded = site_height([0.0, 0.0, 1.5], map_z, "map_2", 7, start_z=10.0)  # recorded poses: own origin
    assert recorded["above_start_m"] == -8.5 and recorded["start_frame"] == 7
    assert site_height([0.0, 0.0, -3.0], np.zeros(0), "map", 0)["above_ground_m"] is None


def test_simulate_text_is_sentences_with_rounded_figures(tmp_path: Path) -> None:
    m = {"success": True, "reason": "landed", "landing_time_s": 12.294117, "phases_s": {"approach": 0.0,
         "ibvs": 8.37, "descent": 3.924}, "recoveries": 1, "touchdown_error_m": 0.034567, "touchdown_speed_m_s": 0.2,
         "final_feature_error_px": 1.23456, "final_yaw_error_deg": None, "stabilisation_time_s": 6.2,
         "max_tilt_deg": 15.994127}
    text = simulate_text(m, tmp_path)
    assert text.startswith("Landed (landed) after 12.3 s.")
    assert "phases: approach 0.0 s, ibvs 8.4 s, descent 3.9 s; 1 recovery" in text
    assert "max tilt 16.0 deg" in text and "touch-down error 0.03 m" in text and "yaw error n/a" in text
    assert "{" not in text and "15.99" not in text


def test_truth_columns_leave_when_no_row_has_truth() -> None:
    row = ["rec", "fuzzy", "site", *["n/a"] * 6, "1.0 / 2.0", "0.10", "both empty"]
    head, rows, dropped = without_empty_truth(TABLE_HEAD, [row])
    assert dropped and head == ("recording", "method", "status", "frame ms (med/p90)", "site dist m", "mask IoU")
    assert rows == [["rec", "fuzzy", "site", "1.0 / 2.0", "0.10", "both empty"]]
    with_truth = ["rec", "fuzzy", "site", "0.900", *["n/a"] * 5, "1.0 / 2.0", "0.10", "0.5"]
    assert without_empty_truth(TABLE_HEAD, [row, with_truth])[2] is False  # one row with truth keeps them


def test_usage_errors_use_slz_error_style() -> None:
    res = CliRunner().invoke(main, ["detect", "x", "--bogus"])
    assert res.exit_code == 2
    assert res.stderr.splitlines()[-1].startswith("slz: error: No such option '--bogus'")
    assert "Error:" not in res.stderr.replace("slz: error:", "")
    res = CliRunner().invoke(main, ["detect", "x", "--timeout", "0"])
    assert res.exit_code == 2 and "not in the range x>0" in res.stderr


def test_every_command_help_has_an_example_and_whole_short_sentences() -> None:
    top = CliRunner().invoke(main, ["-h"]).output
    commands = [ln.split()[0] for ln in top.split("Commands:")[1].splitlines() if ln.strip()]
    assert all(ln.rstrip().endswith(".") and not ln.rstrip().endswith("...")
               for ln in top.split("Commands:")[1].splitlines() if ln.strip())
    leaves = {"config": ["dump"], "land": ["simulate"], "vocab": ["build"]}
    for c in commands:
        for sub in leaves.get(c, [None]):
            args = [c, sub] if sub else [c]
            text = CliRunner().invoke(main, [*args, "-h"]).output
            assert "Example" in text and f"slz {' '.join(args)} " in text, args
    assert "[0<x<=" not in CliRunner().invoke(main, ["detect", "-h"]).output


def test_the_fused_advice_is_its_own_record_rounded_as_it_says() -> None:
    """The fused map's advice becomes landing.json's and the summary's ``advice`` (records.DecideAdvice), with the
    figures rounded as its text gives them, and reads back from the JSON unchanged."""
    from slzcli.fusion.advice import Advice
    from slzcli.outputs.records_json import from_json, to_json_object
    from slzcli.records import DecideAdvice

    a = Advice(x_m=1.23456, y_m=-2.0, factor=3.0, frames=12, sideways_m=1.2345, descend_to_m=None, hover=False)
    rec = a.record()
    assert rec == DecideAdvice("fused", a.text(), 12, 1.23, None, False, 1.235, -2.0)
    assert "12 more frames or 1.2 m of sideways flight" in rec.text
    assert from_json(DecideAdvice, to_json_object(rec)) == rec
    hover = Advice(0.0, 0.0, 5.0, None, 2.0, 4.5, True).record()
    assert hover.hover and hover.frames is None and hover.descend_to_m == 4.5
    assert hover.text == ("hovering: more frames will not decide the ground at (0.0, 0.0) m; move: fly 2.0 m sideways "
                          "or descend to 4.5 m")
    assert Advice(0.0, 0.0, 5.0, 1, None, None, False).text() == "to decide the ground at (0.0, 0.0) m: 1 more frame"


def test_a_run_whose_frames_could_not_vouch_is_told_the_altitude_that_would() -> None:
    """Per-frame methods: without a site, when depth noise kept the detection frames from vouching, the advice is
    the altitude below which the highest of them would have vouched (``limits.vouchable_altitude_m``), and it does
    vouch there and not above; the no-site reason names the same altitude and what the noise hides (one
    ``limits.would_vouch`` for both, texts as before); without unvouched frames there is no advice; the method's
    own advice wins."""
    from slzcli.config import load_config
    from slzcli.records import DecideAdvice
    from slzcli.summary import RunState, decide_advice
    from slzcli.terrain.limits import limit_reason, working_scale, would_vouch
    from slzcli.types import DepthNoise

    cfg = load_config()
    # correlated over every block scale, as stereo error is: it cannot vouch at 7.5 m
    noise = DepthNoise((0.003,) * 5, "known", 0, 0.0)
    work = working_scale(noise, 7.5, 600.0, cfg.terrain, cfg.uav)
    assert not work.vouched
    assert decide_advice(RunState()) is None
    st = RunState(unvouched=1, worst_unvouched=work, would_vouch=would_vouch(work, cfg.terrain, cfg.uav))
    adv = decide_advice(st)
    assert adv is not None and adv.source == "depth_limits" and adv.descend_to_m is not None
    assert 0.3 < adv.descend_to_m < 7.5
    assert adv.text == f"descend below {adv.descend_to_m:.1f} m (at 7.5 m the depth noise hides {work.hidden()})"
    assert st.unvouched_reason == limit_reason(work, cfg.terrain, cfg.uav) == (
        f"at 7.5 m the depth noise (sigma ~ {work.sigma_m:.2f} m) hides {work.hidden()}; "
        f"below {adv.descend_to_m:.1f} m it would not")
    assert working_scale(noise, adv.descend_to_m - 0.05, 600.0, cfg.terrain, cfg.uav).vouched
    assert not working_scale(noise, adv.descend_to_m + 0.05, 600.0, cfg.terrain, cfg.uav).vouched
    own = DecideAdvice("fused", "to decide the ground at (1.0, 2.0) m: 3 more frames", frames=3)
    assert decide_advice(RunState(unvouched=1, worst_unvouched=work, advice=own)) is own
