"""`slz compare` (issue 8): fuzzy vs Bayes on the same frames, checked against ground truth.

Recordings are rendered at 320x240 (camera.* overrides) with few frames so the module stays fast.
The end-to-end test spies on ``Fusion.__call__`` to get every detection both methods made, and
recomputes the report's numbers from those arrays and the ground truth, independently of the
aggregation code (``total``, ``precision_recall_curve`` and ``site_truth`` from evaluate/safety).
"""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, fusion_spy, synth_recording

from slzcli.cli import main
from slzcli.compare import CurveCounts, check_same_inputs, resolve_methods
from slzcli.compare_records import Comparison, MethodComparison, PairComparison, VariantRow
from slzcli.errors import ConfigError
from slzcli.evaluate.safety import mask_counts
from slzcli.outputs import report
from slzcli.outputs.records_json import from_json, to_json_object
from slzcli.outputs.summary_json import rounded
from slzcli.types import Detection

SMALL = (*GAUSSIAN, "--set", "camera.width=320", "--set", "camera.height=240", "--set", "camera.fx=231.0685",
         "--set", "camera.fy=231.0685", "--set", "camera.cx=160", "--set", "camera.cy=120")
FRAMES = 6


@pytest.fixture(scope="module")
def clear_field(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("flights") / "clear_field.mcap", "clear_field", FRAMES, *SMALL)


@pytest.fixture(scope="module")
def compared(clear_field, tmp_path_factory):
    """One comparison of clear_field, with every Detection each method produced captured."""
    from click.testing import CliRunner

    out = tmp_path_factory.mktemp("cmp") / "out"
    with fusion_spy() as seen:
        res = CliRunner().invoke(main, ["compare", str(clear_field), "-o", str(out), "--json", *SMALL])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout), out, seen


def _by_method(seen):
    out: dict[str, list[Detection]] = {}
    for m, d in seen:
        out.setdefault(m, []).append(d)
    return out


def test_report_numbers_equal_a_recomputation_against_ground_truth(compared, clear_field) -> None:
    from slzcli.evaluate.safety import mask_counts, precision_recall_curve, site_truth, total
    from slzcli.synth.groundtruth import load_ground_truth

    summary, out, seen = compared
    report = json.loads((out / "compare.json").read_text())
    assert rounded(report["recordings"]) == summary["recordings"]  # --json: the same numbers, rounded
    rec = report["recordings"][0]
    gt = load_ground_truth(clear_field)
    dets = _by_method(seen)
    assert set(dets) == {"fuzzy", "bayes"} and len(dets["fuzzy"]) == rec["detections"] > 0
    levels = np.linspace(0.0, 1.0, 101)
    for m in ("fuzzy", "bayes"):
        entry = rec["methods"][m]["ground_truth"]
        truths = [gt.safe_mask(d.frame.stamp_ns, tolerance_ns=1_000_000) for d in dets[m]]
        counts = total(mask_counts(d.score.mask, t) for d, t in zip(dets[m], truths, strict=True))
        for key in ("precision", "recall", "iou"):
            assert entry["mask"][key] == pytest.approx(getattr(counts, key), abs=1e-12), (m, key)
        # The sweep: precision_recall_curve on every pixel of every detection frame at once.
        scores = np.concatenate([d.score.score.ravel() for d in dets[m]])
        truth = np.concatenate([t.ravel() for t in truths])
        precision, recall = precision_recall_curve(scores, truth, levels)
        best: dict[float, float] = {}
        for r, p in zip(recall, precision, strict=True):
            best[r] = max(best.get(r, 0.0), p)
        rs = sorted(best)
        ap = sum((r1 - r0) * best[r1] for r0, r1 in zip([0.0, *rs[:-1]], rs, strict=True))
        assert entry["pr_auc"] == pytest.approx(ap, abs=1e-9), m
        # The committed site: truly safe, clearance through the TRUE pose of its frame (the right answer is clear).
        site = rec["methods"][m]["site"]
        assert rec["methods"][m]["status"] == "site" and site is not None
        T = gt.T_world_camera[gt.index_of(site["stamp_ns"], tolerance_ns=1_000_000)]
        p = T[:3, :3] @ np.asarray(site["center_camera"]) + T[:3, 3]
        st = site_truth(gt.raster, (float(p[0]), float(p[1])))
        assert entry["site"]["safe"] is st.safe is True, m
        assert entry["site"]["clearance_m"] == pytest.approx(st.clearance_m), m
        assert st.clearance_m > 0.5 * 0.656
        # open grass: both masks must be nearly all truly safe
        assert counts.precision is not None and counts.precision >= 0.9, m
    pair = rec["pairs"][0]
    agree = total(mask_counts(a.score.mask, b.score.mask) for a, b in zip(dets["fuzzy"], dets["bayes"], strict=True))
    assert pair["mask_iou"] == pytest.approx(agree.iou)
    sites = {m: np.asarray(rec["methods"][m]["site"]["center_world"]) for m in ("fuzzy", "bayes")}
    assert pair["site_distance_m"] == pytest.approx(float(np.linalg.norm(sites["fuzzy"] - sites["bayes"])))
    # The CSV carries the same numbers as the JSON.
    import csv

    rows = {r["method"]: r for r in csv.DictReader((out / "compare.csv").open())}
    for m in ("fuzzy", "bayes"):
        assert float(rows[m]["precision"]) == pytest.approx(rec["methods"][m]["ground_truth"]["mask"]["precision"])
        assert rows[m]["site_safe"] == "True"


def test_both_methods_get_the_same_frames_points_and_maps(compared) -> None:
    summary, _, seen = compared
    rec = summary["recordings"][0]
    assert rec["inputs_identical"] is True
    inputs = {m: rec["methods"][m]["inputs"] for m in ("fuzzy", "bayes")}
    assert inputs["fuzzy"] == inputs["bayes"] and len(inputs["fuzzy"]) == rec["detections"]
    dets = _by_method(seen)
    assert [d.frame.index for d in dets["fuzzy"]] == [d.frame.index for d in dets["bayes"]]
    with_points = 0
    for a, b in zip(dets["fuzzy"], dets["bayes"], strict=True):
        assert a.frame is b.frame and a.maps is b.maps          # computed once, handed to both
        assert a.points is b.points
        if a.points is not None:
            with_points += 1
            assert np.array_equal(a.points.xyz_world, b.points.xyz_world)
        assert a.timings_ms["maps"] == b.timings_ms["maps"]
    assert with_points > 0
    # The in-code check refuses inputs that differ.
    check_same_inputs({"fuzzy": [(0, 1, "a", "m")], "bayes": [(0, 1, "a", "m")]})
    with pytest.raises(RuntimeError, match="different frames"):
        check_same_inputs({"fuzzy": [(0, 1, "a", "m")], "bayes": [(0, 1, "b", "m")]})


def test_outputs_table_figures_and_report(compared) -> None:
    summary, out, _ = compared
    for name in ("compare.json", "compare.csv", "report.html", "clear_field/figure6.png",
                 "clear_field/pr_curves.png", "clear_field/timing.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 3 and "fuzzy vs bayes" in html
    t = summary["recordings"][0]["methods"]["fuzzy"]["timings_ms"]
    assert set(t) == {"slam", "maps", "score", "mask", "select", "frame"}
    assert t["frame"]["p90_ms"] >= t["frame"]["median_ms"] > 0


def test_compare_json_round_trips_through_the_records(compared) -> None:
    """compare.json is the records' JSON: read back into them and written again it is the same text, key order
    included, and compare.csv made from the records read back is the file's text."""
    summary, out, _ = compared
    doc = json.loads((out / "compare.json").read_text())
    back = from_json(Comparison, doc)
    rec = back.recordings[0]
    assert isinstance(rec.methods["fuzzy"], MethodComparison) and isinstance(rec.pairs[0], PairComparison)
    assert rec.methods["bayes"].ground_truth is not None and rec.slam.frames_digest
    again = {"slz_output": doc["slz_output"], **to_json_object(back), "config": doc["config"]}
    assert json.dumps(again) == json.dumps(doc)
    assert report.csv_text(back.recordings) == (out / "compare.csv").read_text()
    # the --json summary: the same record, rounded, then the output folder
    assert list(summary) == ["schema_version", "command", *to_json_object(back), "output"]
    # the mask figures keep the key order of the pixel counts they come from
    counts = mask_counts(np.ones((2, 2), bool), np.eye(2, dtype=bool))
    gt = rec.methods["fuzzy"].ground_truth
    assert gt is not None and [f.name for f in fields(gt.mask)] == list(counts.as_dict())


def test_stdout_table(runner, clear_field, tmp_path) -> None:
    res = runner.invoke(main, ["compare", str(clear_field), "-o", str(tmp_path / "c"), "--methods", "bayes,fuzzy",
                               *SMALL])
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert lines[0].split()[:3] == ["recording", "method", "status"]
    assert lines[1].split()[:2] == ["clear_field", "bayes"] and lines[2].split()[:2] == ["clear_field", "fuzzy"]
    assert "identical for all methods" in res.stdout


def test_variants_rerender_the_scene_and_report_the_change(runner, tmp_path) -> None:
    rec = tmp_path / "cf.mcap"
    assert runner.invoke(main, ["synth", "clear_field", "-o", str(rec), "--frames", "3", *SMALL]).exit_code == 0
    res = runner.invoke(main, ["compare", str(rec), "-o", str(tmp_path / "c"), "--variants", "--json",
                               "--set", "compare.variants=[sand]", *SMALL])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert (tmp_path / "c" / "variants" / "cf" / "clear_field_sand.mcap").exists()
    [variant] = summary["variants"]
    assert variant["scene"]["variants"] == ["sand"] and variant["variant_of"] == "cf"
    base, row = summary["variant_table"]
    assert base["variant"] == "base" and row["variant"] == "sand"
    for m in ("fuzzy", "bayes"):
        change = row["change"]["methods"][m]["precision"]
        assert change == pytest.approx(row["methods"][m]["precision"] - base["methods"][m]["precision"])
    assert set(row["maps"]) == {"depth_variance", "flatness", "inclination", "steepness"}
    assert (tmp_path / "c" / "variants_cf.png").is_file()
    # the variants and their table round-trip through the records, key order included
    plain = {k: v for k, v in summary.items() if k not in ("schema_version", "command", "output")}
    back = from_json(Comparison, plain)
    assert isinstance(back.variant_table[1], VariantRow) and back.variant_table[1].change is not None
    assert back.variants[0].variant_of == "cf" and back.variants[0].scene is not None
    assert json.dumps(to_json_object(back)) == json.dumps(plain)


# ----------------------------------------------------------------------------- bad input
def _one_line_error(res, *needles: str) -> None:
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("slz: error:"), res.stderr
    assert "Traceback" not in res.output
    for n in needles:
        assert n in lines[0], lines[0]


def test_missing_recording_exit_1_and_no_output(runner, tmp_path) -> None:
    out = tmp_path / "out"
    res = runner.invoke(main, ["compare", str(tmp_path / "nope.mcap"), "-o", str(out)])
    _one_line_error(res, "nope.mcap")
    assert not out.exists()


def test_garbage_recording_leaves_no_partial_folder(runner, tmp_path) -> None:
    bad = tmp_path / "garbage.mcap"
    bad.write_bytes(b"\x00not an mcap file" * 50)
    out = tmp_path / "out"
    res = runner.invoke(main, ["compare", str(bad), "-o", str(out)])
    _one_line_error(res, "garbage.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.mcap"]


def test_bad_methods_and_bad_config_exit_1(runner, clear_field, tmp_path) -> None:
    out = tmp_path / "out"
    _one_line_error(runner.invoke(main, ["compare", str(clear_field), "-o", str(out), "--methods", "fuzzy,fuzzi"]),
                    "--methods", "fuzzi")
    _one_line_error(runner.invoke(main, ["compare", str(clear_field), "-o", str(out), "--methods", "fuzzy"]),
                    "--methods")
    _one_line_error(runner.invoke(main, ["compare", str(clear_field), "-o", str(out),
                                         "--set", "compare.pr_levels=1"]), "compare.pr_levels")
    assert not out.exists()


def test_variants_need_a_synth_recording(runner, clear_field, tmp_path) -> None:
    plain = tmp_path / "plain.mcap"
    plain.write_bytes(clear_field.read_bytes())  # same frames, no ground-truth sidecar
    out = tmp_path / "out"
    res = runner.invoke(main, ["compare", str(plain), "-o", str(out), "--variants", *SMALL])
    _one_line_error(res, "plain.mcap", "--variants")
    assert not out.exists()


def test_existing_output_needs_force(runner, clear_field, tmp_path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    _one_line_error(runner.invoke(main, ["compare", str(clear_field), "-o", str(out)]), "not an slz compare folder")
    _one_line_error(runner.invoke(main, ["compare", str(clear_field), "-o", str(out), "--force"]),
                    "not an slz compare folder")  # --force replaces a compare folder, never a user's folder
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"] and (out / "keep.txt").read_text() == "x"


# ----------------------------------------------------------------------------- units
def test_curve_counts_equal_precision_recall_curve_and_add_up_over_frames() -> None:
    from slzcli.evaluate.safety import precision_recall_curve

    rng = np.random.default_rng(3)
    frames = [(rng.random((40, 50)).astype(np.float32), rng.random((40, 50)) > 0.4) for _ in range(3)]
    frames[0][0][:5] = 1.0   # ties at the top, as a saturated Bayes score has
    frames[1][0][:, :3] = 0.0
    cc = CurveCounts.empty(21)
    for s, t in frames:
        cc.add(s, t)
    p, r = cc.curve()
    p_ref, r_ref = precision_recall_curve(np.concatenate([s.ravel() for s, _ in frames]),
                                          np.concatenate([t.ravel() for _, t in frames]), np.linspace(0, 1, 21))
    assert np.allclose(p, p_ref) and np.allclose(r, r_ref)


def test_curve_area_perfect_saturated_and_no_positives() -> None:
    truth = np.array([True, True, False, False])
    perfect = CurveCounts.empty(11)
    perfect.add(np.array([0.9, 0.8, 0.1, 0.2]), truth)
    assert perfect.auc() == pytest.approx(1.0)
    flat = CurveCounts.empty(11)   # a score that says 1.0 everywhere: precision is the base rate over all recall
    flat.add(np.array([1.0, 1.0, 1.0, 1.0]), truth)
    assert flat.auc() == pytest.approx(0.5)
    none = CurveCounts.empty(11)
    none.add(np.array([0.5, 0.5]), np.array([False, False]))
    assert none.auc() is None


def test_resolve_methods() -> None:
    assert resolve_methods(["fuzzy", " bayes", "fuzzy"]) == ("fuzzy", "bayes")
    with pytest.raises(ConfigError, match="unknown method 'baes'"):
        resolve_methods(["fuzzy", "baes"])
    with pytest.raises(ConfigError, match="at least two"):
        resolve_methods(["bayes"])


def test_without_ground_truth_no_empty_truth_columns(runner, clear_field, tmp_path) -> None:
    """The same recording with its ground truth sidecar taken away: the table has no column of n/a."""
    import shutil

    bare = tmp_path / "bare.mcap"
    shutil.copy(clear_field, bare)  # the sidecar (.gt.npz) stays behind: no ground truth
    res = runner.invoke(main, ["compare", str(bare), "-o", str(tmp_path / "c"), *SMALL])
    assert res.exit_code == 0, res.output
    head = res.stdout.splitlines()[0].split()
    assert "precision" not in head and "recall" not in head and "IoU" in head  # mask IoU between the methods
    assert "no ground truth" in res.stdout
    rows = res.stdout.splitlines()[1:3]
    assert all("n/a n/a" not in " ".join(r.split()) for r in rows), res.stdout
    page = (tmp_path / "c" / "report.html").read_text()
    assert "<th>precision</th>" not in page
