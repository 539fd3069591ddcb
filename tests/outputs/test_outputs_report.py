"""The detect report (report.html), colour bars on the per-frame PNGs, points.ply of a run, progress off a terminal."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, synth_recording

from slzcli.cli import main
from slzcli.outputs import images, palette
from slzcli.outputs.detect_report import SECTIONS
from slzcli.outputs.points import NO_CLUSTER, ROLES, read_points_ply

FRAMES = 6
MAPS = ("depth_variance", "flatness", "inclination", "steepness")


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("rep") / "clear.mcap", "clear_field", FRAMES, *GAUSSIAN)


@pytest.fixture(scope="module")
def run(recording, tmp_path_factory) -> tuple[Path, str]:
    """One run at --outputs all, a progress line on every frame (CliRunner's stderr is not a terminal)."""
    out = tmp_path_factory.mktemp("run") / "run"
    res = CliRunner().invoke(main, ["detect", str(recording), "-o", str(out), "--outputs", "all",
                                    "--set", "output.progress_every_s=0"])
    assert res.exit_code == 0, res.output
    return out, res.stderr


def links(page: str) -> list[str]:
    return [u for u in re.findall(r"""(?:href|src)=['"]?([^'" >]+)""", page) if not u.startswith("data:")]


def test_report_has_every_section_and_its_links_resolve(run) -> None:
    out, _ = run
    page = (out / "report.html").read_text()
    for section in SECTIONS:
        assert f"id={section}>" in page, section
    for url in links(page):
        assert (out / url).is_file(), url
    overlays = [u for u in links(page) if u.endswith("overlay.png")]
    summary = json.loads((out / "run.json").read_text())["summary"]
    assert len(set(overlays)) == summary["detections"] > 0  # every detection's overlay, linked not copied
    # The Figure 5 panel: one inlined JPEG, 2 rows of 4 tiles (maps, score, mask, slope, overlay) with titles.
    figures = [cv2.imdecode(np.frombuffer(base64.b64decode(b), np.uint8), cv2.IMREAD_COLOR)
               for b in re.findall(r"data:image/jpeg;base64,([A-Za-z0-9+/=]+)", page)]
    assert len(figures) == 1 and figures[0] is not None
    tile_h = 240 + 24   # 640x480 frames drawn 320 px wide, under a 24 px title band
    assert figures[0].shape[0] == 2 * tile_h and figures[0].shape[1] >= 4 * 320
    # The trajectory: inline SVG with the camera path, each site and the committed square.
    svg = page[page.index("id=trajectory>"):]
    assert "<svg" in svg and "<polyline" in svg and "<polygon" in svg
    landing = json.loads((out / "landing.json").read_text())
    assert landing["status"] == "site"
    assert f"frame {landing['frame']['index']}" in page and "class=committed" in page
    assert page.count("<tr class=committed>") == 1


def test_per_frame_heat_maps_have_a_colour_bar_and_the_mask_a_legend(run) -> None:
    out, _ = run
    folder = sorted((out / "frames").iterdir())[0]
    with np.load(folder / "maps.npz") as z:
        h, w = z["mask"].shape
        mask = z["mask"]
    top = images.BAR_MARGIN_PX + 8 + 2
    bottom = h - images.BAR_MARGIN_PX - 8 - 3
    column = w + images.BAR_MARGIN_PX + images.BAR_GRADIENT_PX // 2
    cmap = cv2.applyColorMap(np.array([[255], [0]], np.uint8), palette.CV2_COLORMAP)[:, 0]  # 1 then 0
    for name in (*MAPS, "score"):
        img = cv2.imread(str(folder / f"{name}.png"), cv2.IMREAD_COLOR)
        assert img is not None and img.shape == (h, w + images.BAR_WIDTH_PX, 3), name
        # the bar runs from viridis(1) at the top to viridis(0) at the bottom (default colour convention)
        assert np.abs(img[top, column].astype(int) - cmap[0]).max() <= 12, name
        assert np.abs(img[bottom, column].astype(int) - cmap[1]).max() <= 12, name
        assert img[:, w:].any(axis=2).sum() > 0.05 * h * images.BAR_WIDTH_PX  # not an empty strip
    m = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_UNCHANGED)
    assert m is not None and m.shape == (h, w + images.LEGEND_WIDTH_PX)
    assert np.array_equal(m[:, :w], mask.astype(np.uint8) * 255)  # the mask's pixels are unchanged


def test_points_ply_of_a_run_has_each_point_once_with_role_and_cluster(run) -> None:
    out, _ = run
    v = read_points_ply(out / "points.ply")
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    assert len(np.unique(xyz, axis=0)) == len(v) > 0
    site = json.loads((out / "landing.json").read_text())["site"]
    corner = v["role"] == ROLES.index("corner")
    np.testing.assert_allclose(np.sort(xyz[corner], axis=0), np.sort(np.array(site["corners_world"]), axis=0),
                               atol=1e-5)
    chosen, kept = v["role"] == ROLES.index("chosen"), v["role"] == ROLES.index("kept")
    assert 0 < chosen.sum() <= site["cluster"]["points"]
    assert len(set(v["cluster"][chosen])) == 1 and v["cluster"][chosen][0] >= 0
    assert np.all(v["cluster"][kept] >= 0) and v["cluster"][chosen][0] not in set(v["cluster"][kept])
    assert set(v["cluster"][~(chosen | kept)]) == {NO_CLUSTER}


def test_progress_lines_off_a_terminal(run, recording, tmp_path) -> None:
    _, stderr = run
    lines = [ln for ln in stderr.splitlines() if ln.startswith("slz: detect: ")]
    assert [int(ln.split()[2]) for ln in lines] == list(range(1, FRAMES + 1))  # every 0 s: each frame
    assert all("frames/s" in ln for ln in lines)
    res = CliRunner().invoke(main, ["detect", str(recording), "-o", str(tmp_path / "r"), "--outputs", "summary"])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: detect: ")]
    assert lines and lines[0].startswith(f"slz: detect: 1 of {FRAMES} frames")  # the first frame at once,
    assert lines[-1].startswith(f"slz: detect: {FRAMES} of {FRAMES} frames (100 %)")  # then every 5 s and the last


def test_report_at_summary_level_says_what_is_missing(recording, tmp_path) -> None:
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["detect", str(recording), "-o", str(out), "--outputs", "summary"])
    assert res.exit_code == 0, res.output
    page = (out / "report.html").read_text()
    assert "Not drawn: frame folders are not written at --outputs summary" in page
    assert "No frame folders at --outputs summary" in page and "id=trajectory>" in page
    assert all((out / u).is_file() for u in links(page))
