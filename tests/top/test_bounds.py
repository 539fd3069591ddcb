"""Limits before allocation (issue 15): pixel bound from image headers, bounded YAML, bounded messages,
config-implied sizes (footprint, blur, raster, simulation steps), chunked Monte Carlo, SIGTERM.

No wall-clock asserts: where a test needs a subprocess to end, its timeout only guards the test
run against a hang, and the work it stands against is orders of magnitude longer.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import bad_inputs as B
import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from slzcli.cli import main, one_line
from slzcli.config import YamlLimitError, load_config, safe_yaml_load
from slzcli.errors import ConfigError, DecodeError, short_repr
from slzcli.sources import decode
from slzcli.sources.image_limits import FrameTooLarge, compressed_size

REPO = Path(__file__).resolve().parents[2]


# ----------------------------------------------------------------------------- image headers
class _Compressed:
    __msgtype__ = "sensor_msgs/msg/CompressedImage"

    def __init__(self, data: bytes, fmt: str = "png") -> None:
        self.data = np.frombuffer(data, dtype=np.uint8)
        self.format = fmt


def test_header_sizes_of_real_png_and_jpeg() -> None:
    img = np.zeros((37, 53, 3), np.uint8)
    for ext, kind in ((".png", "png"), (".jpg", "jpeg")):
        ok, buf = cv2.imencode(ext, img)
        assert ok and compressed_size(buf) == (53, 37, kind)
    # an APP1 (EXIF-like) segment before the frame header is walked over
    ok, jpg = cv2.imencode(".jpg", img)
    app1 = b"\xff\xe1" + (2 + 300).to_bytes(2, "big") + b"\x00" * 300
    assert compressed_size(jpg.tobytes()[:2] + app1 + jpg.tobytes()[2:])[:2] == (53, 37)
    assert compressed_size(B.png_header(12000, 9000)) == (12000, 9000, "png")
    assert compressed_size(B.jpeg_header(30000, 30000)) == (30000, 30000, "jpeg")


@pytest.mark.parametrize("data", [b"", b"GIF89a....", b"\x89PNG\r\n\x1a\n\0\0", b"\xff\xd8\xff\xd9",
                                  b"\xff\xd8\x00\x00\x00\x00"])
def test_no_readable_header_is_a_decode_error(data: bytes) -> None:
    with pytest.raises(DecodeError, match="not a decodable jpeg/png"):
        compressed_size(data)


def test_oversized_frame_is_refused_before_imdecode(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_decode(*args: object) -> None:
        raise AssertionError("cv2.imdecode called on a frame over the bound")

    monkeypatch.setattr(decode.cv2, "imdecode", no_decode)
    with pytest.raises(FrameTooLarge, match=r"12000x9000 px \(108.0 MP\) is over sources.max_image_px 1000000"):
        decode.decode_color(_Compressed(B.png_header(12000, 9000)), max_px=1_000_000)


def test_over_opencv_own_limit_is_a_decode_error_not_a_crash() -> None:
    """With no slz bound, OpenCV throws cv2.error (not None) over CV_IO_MAX_IMAGE_PIXELS: one frame, one skip."""
    with pytest.raises(DecodeError, match="not a decodable jpeg/png"):
        decode.decode_color(_Compressed(B.png_header(40000, 30000)), max_px=0)


def test_raw_image_declaring_too_many_pixels_is_refused() -> None:
    class Raw:
        __msgtype__ = "sensor_msgs/msg/Image"
        encoding, width, height, step, is_bigendian = "16UC1", 30000, 30000, 60000, 0
        data = np.zeros(16, np.uint8)

    with pytest.raises(FrameTooLarge, match="Image 16UC1 of 30000x30000 px"):
        decode.decode_depth(Raw(), 0.001, max_px=16_777_216)


def test_tum_frame_over_the_bound_is_skipped(tmp_path: Path) -> None:
    from slzcli.sources import open_recording

    folder = tmp_path / "tum"
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb_lines, depth_lines = [], []
    for i in range(3):
        t = f"{1305031102 + i}.000000"
        rgb = B.png_header(9000, 9000) if i == 1 else cv2.imencode(".png", np.zeros((120, 160, 3), np.uint8))[1]
        (folder / "rgb" / f"{i}.png").write_bytes(bytes(rgb))
        cv2.imwrite(str(folder / "depth" / f"{i}.png"), np.full((120, 160), 5000, np.uint16))
        rgb_lines.append(f"{t} rgb/{i}.png")
        depth_lines.append(f"{t} depth/{i}.png")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    with open_recording(folder, load_config()) as rec:
        frames = list(rec.frames())
    assert len(frames) == 2 and rec.report.undecodable == 1
    assert any("over sources.max_image_px" in n for n in rec.report.notes)


# ----------------------------------------------------------------------------- bounded YAML and messages
def test_yaml_loader_bounds() -> None:
    assert safe_yaml_load("a: &x [1, 2]\nb: *x\n") == {"a": [1, 2], "b": [1, 2]}   # a few aliases are fine
    for text, why in ((B.alias_bomb(9), "values once its aliases are expanded"),
                      ("[" * 40 + "]" * 40, "nested more than 32"),
                      ("[" + ", ".join(["*a"] * 102).replace("*a", "&a 1", 1) + "]", "more than 100 aliases")):
        with pytest.raises(YamlLimitError, match=why):
            safe_yaml_load(text)
    assert isinstance(YamlLimitError("x"), yaml.YAMLError)
    # YAML 1.2 floats (PyYAML reads 1e-9 as a string)
    assert safe_yaml_load("[1e-9, 1e6, 2.5E+3, 7, abc]") == [1e-9, 1e6, 2500.0, 7, "abc"]


def test_short_repr_and_one_line_stay_short() -> None:
    bomb = safe_yaml_load(B.alias_bomb(5))
    assert len(short_repr(bomb)) <= 80 and short_repr(bomb).startswith("[[[[...]")
    assert short_repr("x" * 10**6).endswith("...") and len(short_repr("x" * 10**6, 40)) == 40
    assert short_repr(3.5) == "3.5"
    text = one_line("file.yaml: " + "word\n" * 10**6 + "the cause")
    assert len(text) <= 2000 and text.startswith("file.yaml: word word") and text.endswith("the cause")


# ----------------------------------------------------------------------------- windows larger than the image
def test_min_filter_wider_than_the_image_is_zero_without_a_kernel() -> None:
    from slzcli.scoring.mask import min_filter

    score = np.ones((48, 64), np.float32)
    out = min_filter(score, 21_333_335, 21_333_335)   # uav.footprint_m=[1e6, 1e6] at 6 m: 414 TiB of kernel
    assert out.shape == score.shape and not out.any()
    assert np.array_equal(min_filter(score, 63, 47), cv2.erode(score, np.ones((47, 63), np.uint8),
                                                                 borderType=cv2.BORDER_CONSTANT, borderValue=0))


def test_smoothing_kernel_stops_at_the_image_size(monkeypatch: pytest.MonkeyPatch) -> None:
    from slzcli.scoring import mask

    rng = np.random.default_rng(0)
    score = rng.random((48, 64)).astype(np.float32)
    for sigma in (0.7, 3.0, 7.5):   # narrower than the image: the same as OpenCV's own kernel size
        assert np.array_equal(mask.smooth(score, sigma, sigma), cv2.GaussianBlur(score, (0, 0), sigma, sigmaY=sigma))
    sizes: list[tuple[int, int]] = []
    real = cv2.GaussianBlur

    def recorded(img: np.ndarray, k: tuple[int, int], sigmaX: float, sigmaY: float) -> np.ndarray:
        sizes.append(k)
        return real(img, k, sigmaX=sigmaX, sigmaY=sigmaY)

    monkeypatch.setattr(mask.cv2, "GaussianBlur", recorded)
    mask.smooth(score, 77_000.0, 77_000.0)   # mask.smooth_m=1000 at 6 m: OpenCV would take 616,001 taps
    assert sizes == [(2 * 64 + 1, 2 * 48 + 1)]


def test_ground_truth_footprint_larger_than_the_scene_is_unsafe_without_a_kernel() -> None:
    from slzcli.synth.groundtruth import compute_raster

    def cast(origins: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
        n = len(origins)
        return {"t": np.full(n, 5.0), "part": np.zeros(n, int), "hit": np.ones(n, bool),
                "normal": np.tile([0.0, 0.0, 1.0], (n, 1))}

    cfg = load_config(overrides=["uav.footprint_m=[1e6, 1e6]"])
    raster = compute_raster(cast, (0.0, 4.0, 0.0, 4.0), 5.0, np.array([True]), np.array([1], np.uint16), cfg.uav,
                            cfg.synth.ground_truth)
    assert raster.usable.all() and not raster.safe.any()


def test_normals_refuse_a_radius_that_joins_every_pair() -> None:
    from slzcli.landing.select import point_normals

    xyz = np.random.default_rng(0).random((300, 3))
    up = np.array([0.0, 0.0, 1.0])
    with pytest.raises(ConfigError, match=r"joins 4\.48e\+04 pairs of the 300 map points") as err:
        point_normals(xyz, 1000.0, up, max_pairs=10_000)   # 300 x 299 / 2 = 44,850 pairs
    assert err.value.key == "landing.normal_radius_m"
    assert np.array_equal(point_normals(xyz, 0.2, up, max_pairs=10_000), point_normals(xyz, 0.2, up), equal_nan=True)


# ----------------------------------------------------------------------------- sizes a config implies
@pytest.mark.parametrize("overrides,runs,key,what", [
    (["control.sim.dynamics_dt_s=1e-9"], 1, "control.sim.dynamics_dt_s", "dynamics steps of one landing"),
    (["control.sim.timeout_s=1e6"], 1, "control.sim.timeout_s", "dynamics steps of one landing"),
    ([], 2_000_000, "--runs", "Monte Carlo runs"),
    ([], 400_000, "--runs", "dynamics steps of the whole batch"),
])
def test_simulation_sizes_are_refused_naming_the_key(overrides: list[str], runs: int, key: str, what: str) -> None:
    from slzcli import bounds

    with pytest.raises(ConfigError, match=what) as err:
        bounds.check(bounds.simulation_sizes(load_config(overrides=overrides), runs))
    assert err.value.key == key
    bounds.check(bounds.simulation_sizes(load_config(), 100_000))   # the tester's --runs 100000 is allowed


def test_synth_sizes_are_refused_naming_the_key() -> None:
    from slzcli import bounds

    big = load_config(overrides=["camera.width=100000", "camera.height=100000", "camera.fx=72000", "camera.fy=72000",
                                 "camera.cx=50000", "camera.cy=50000"])   # the paper's field of view, 100k px wide
    with pytest.raises(ConfigError, match="pixels of each rendered frame") as err:
        bounds.check(bounds.synth_sizes(big))
    assert err.value.key == "camera.width"
    fine = load_config(overrides=["synth.ground_truth.raster_m=0.005"])
    with pytest.raises(ConfigError, match="cells of the ground-truth safety raster") as err:
        bounds.check(bounds.synth_sizes(fine, (-20.0, 20.0, -20.0, 20.0)))
    assert err.value.key == "synth.ground_truth.raster_m"
    bounds.check(bounds.synth_sizes(load_config(), (-20.0, 20.0, -20.0, 20.0)))   # the shipped scenes pass


def test_a_landing_with_a_tiny_step_is_refused_before_it_starts(tmp_path: Path, runner: CliRunner) -> None:
    from landing_file import write_landing

    run = tmp_path / "RUN"
    write_landing(run)
    before = set(run.iterdir())
    for args, key in ((["--set", "control.sim.dynamics_dt_s=1e-9"], "control.sim.dynamics_dt_s"),
                      (["--runs", "100000000"], "--runs")):
        res = runner.invoke(main, ["land", "simulate", str(run), *args])
        assert res.exit_code == 1 and res.stderr.startswith(f"slz: error: {key}: "), res.stderr
        assert len(res.stderr.splitlines()) == 1
    assert set(run.iterdir()) == before   # no ibvs/ folder


# ----------------------------------------------------------------------------- Monte Carlo in chunks
def test_chunked_monte_carlo_equals_one_batch_and_holds_one_chunk(monkeypatch: pytest.MonkeyPatch) -> None:
    from montecarlo_util import BASE, run_values, same, target

    from slzcli.control import montecarlo, noise, simulate

    cfg = load_config(overrides=["control.sim.timeout_s=1.0", "control.montecarlo.chunk_runs=2"])
    whole = montecarlo.run(target(), BASE, 5, 4, cfg)
    widths: list[int] = []
    real = noise.FlightNoise

    class Recording(real):  # type: ignore[misc, valid-type]
        def __init__(self, seed: int, runs: int, *args: int) -> None:
            widths.append(runs)
            super().__init__(seed, runs, *args)

    monkeypatch.setattr(simulate, "FlightNoise", Recording)
    chunks: list[tuple[int, int]] = []
    ticks: list[tuple[int, int]] = []
    joined = montecarlo.run_chunked(target(), BASE, 5, 4, cfg, on_chunk=lambda r, first: chunks.append(
        (first, len(r.reason))), progress=lambda done, total, ok: ticks.append((done, total)))
    assert widths == [2, 2, 1]           # the noise block of one chunk at a time, never of all runs
    assert chunks == [(0, 2), (2, 2), (4, 1)] and ticks == [(2, 5), (4, 5), (5, 5)]
    assert all(same(run_values(whole, i), run_values(joined, i)) for i in range(5))


def test_monte_carlo_rows_are_streamed_with_progress_lines(tmp_path: Path, runner: CliRunner) -> None:
    from landing_file import write_landing

    run = tmp_path / "RUN"
    write_landing(run)
    res = runner.invoke(main, ["land", "simulate", str(run), "--offset", "0,0,3", "--runs", "5", "--json",
                               "--set", "control.sim.timeout_s=1", "--set", "control.montecarlo.chunk_runs=2",
                               "--set", "output.progress_every_s=0"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["runs"] == 5
    progress = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: monte carlo:")]
    assert [ln.split()[3:6] for ln in progress] == [["2", "of", "5"], ["4", "of", "5"], ["5", "of", "5"]], res.stderr
    assert all(ln.endswith(" landed") for ln in progress), res.stderr  # successes so far, after the count
    rows = (run / "ibvs" / "montecarlo_runs.csv").read_text().splitlines()
    assert len(rows) == 6 and [r.split(",")[0] for r in rows[1:]] == ["0", "1", "2", "3", "4"]
    assert not [p for p in (run / "ibvs").iterdir() if p.name.startswith(".")]


# ----------------------------------------------------------------------------- SIGTERM
def _slz_subprocess(args: list[str], tmp_path: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{REPO / 'tests'}"}
    return subprocess.Popen([sys.executable, "-m", "slzcli.cli", *args], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_sigterm_stops_a_monte_carlo_batch_and_leaves_no_table(tmp_path: Path) -> None:
    from landing_file import write_landing

    run = tmp_path / "RUN"
    write_landing(run)
    before = set(run.iterdir())
    proc = _slz_subprocess(["land", "simulate", str(run), "--offset", "0,0,3", "--runs", "100000",
                            "--set", "control.montecarlo.chunk_runs=2"], tmp_path)
    assert proc.stderr is not None
    first = proc.stderr.readline()          # the first chunk is done: the batch is under way
    assert first.startswith("slz: monte carlo: 2 of 100000 runs"), first
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)  # a hang guard: the batch itself would run for days
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "slz: interrupted"
    assert set(run.iterdir()) == before   # no half table, no temporary file, no empty ibvs/ folder


LONG_NATIVE_CALL = textwrap.dedent("""
    import sys
    import cv2, numpy as np
    from slzcli.interrupt import sigterm_interrupts
    from slzcli import interrupt
    img = np.ones((3000, 3000), np.float32)
    try:
        with sigterm_interrupts():
            print("ready", flush=True)
            # one OpenCV call of ~10^12 multiply-adds: tens of minutes here, minutes on a fast machine
            interrupt.call_interruptibly(cv2.GaussianBlur, img, (32001, 32001), 4000.0)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        interrupt.exit_now(130)
    sys.exit(0)
""")


def test_sigterm_is_honoured_while_a_native_call_runs(tmp_path: Path) -> None:
    """The handler runs although the computation is one native call that never returns to Python in time."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", LONG_NATIVE_CALL], env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=60)   # hang guard only: the call itself takes far longer
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail("SIGTERM was not acted on while the native call ran")
    assert proc.returncode == 130 and out.strip() == "interrupted", err
