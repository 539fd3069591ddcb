"""The registry of input formats (``sources/formats.py``): how a path is recognised, what the messages
say, and that a format is one reader plus one registry line (a tiny format defined here is found by
``slz info``, ``detect``, the rerun key, batch run names and the recording check of ``--force``)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, HALF_SIZE, synth_recording

from slzcli.cli import main
from slzcli.config import Config, load_config
from slzcli.errors import DatasetError
from slzcli.fingerprint import recording_files
from slzcli.outputs import safe_output
from slzcli.sources import Recording, RecordingInfo, formats, open_recording
from slzcli.sources.formats import recognise
from slzcli.types import Frame, Intrinsics, PairingReport, StreamChoice, StreamInfo

FRAMES = 4
ODOMETRY = ["--set", "slam.backend=odometry"]


# ----------------------------------------------------------------------------- recognition, as before the registry
def _touch(path: Path, data: bytes = b"x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def test_a_path_is_recognised_by_suffix_or_folder_marker(tmp_path: Path) -> None:
    assert recognise(_touch(tmp_path / "a.bag")) == ("ros1", tmp_path / "a.bag")
    assert recognise(_touch(tmp_path / "b.MCAP")) == ("mcap", tmp_path / "b.MCAP")  # suffixes in any case
    bag = tmp_path / "bag"
    _touch(bag / "metadata.yaml")
    assert recognise(bag) == ("ros2", bag)
    assert recognise(_touch(bag / "bag_0.db3")) == ("ros2", bag)  # a storage file stands for its folder
    assert recognise(_touch(bag / "bag_0.mcap")) == ("mcap", bag / "bag_0.mcap")  # a file's own suffix first
    _touch(bag / "rgb.txt")
    assert recognise(bag)[0] == "ros2"  # the registry's order decides between folder markers
    tum = tmp_path / "tum"
    _touch(tum / "depth.txt")
    assert recognise(tum) == ("tum", tum)


def test_the_messages_name_every_registered_format(tmp_path: Path) -> None:
    with pytest.raises(DatasetError) as err:
        recognise(_touch(tmp_path / "x.txt"))
    assert str(err.value).endswith("unknown recording type '.txt': expected .bag, .mcap, a ROS 2 bag folder or "
                                   "a TUM RGB-D folder")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError) as err:
        recognise(tmp_path / "empty")
    assert str(err.value).endswith("folder is neither a ROS 2 bag (no metadata.yaml) nor a TUM RGB-D folder "
                                   "(no rgb.txt)")
    with pytest.raises(DatasetError, match="empty file"):
        recognise(_touch(tmp_path / "e.bag", b""))


# ----------------------------------------------------------------------------- a tiny format, defined here
class TinyRecording(Recording):
    """Frames in one .npz (rgb, depth, stamps, K = fx fy cx cy width height): a reader in a dozen lines."""

    def __init__(self, path: Path, config: Config) -> None:
        super().__init__(path)
        self.arrays: dict[str, np.ndarray] = {}

    def open(self) -> None:
        with np.load(self.path) as z:
            self.arrays = {k: z[k] for k in z.files}

    def close(self) -> None:
        self.arrays = {}

    def _intrinsics(self) -> Intrinsics:
        fx, fy, cx, cy, w, h = self.arrays["K"]
        return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(w), int(h))

    def info(self) -> RecordingInfo:
        stamps = self.arrays["stamps"]
        n = len(stamps)
        streams = tuple(StreamInfo(k, "tiny array", n, int(stamps[0]), int(stamps[-1])) for k in ("rgb", "depth"))
        return RecordingInfo(str(self.path), "tiny", (int(stamps[-1]) - int(stamps[0])) * 1e-9, streams,
                             (StreamChoice("color", "rgb", "the tiny file's"), StreamChoice("depth", "depth",
                                                                                           "the tiny file's")),
                             self._intrinsics(), "the tiny file's K", PairingReport(paired=n))

    def frames(self) -> Iterator[Frame]:
        a = self.arrays
        for i, stamp in enumerate(a["stamps"]):
            yield Frame(i, int(stamp), a["rgb"][i], a["depth"][i], self._intrinsics(), None, str(self.path))
        self.report = PairingReport(paired=len(a["stamps"]))


def tiny_files(path: Path) -> list[Path]:
    return [path]


TINY = formats.Format(TinyRecording, tiny_files, suffixes=(".tiny",), run_suffixes=(".tiny",), magic=b"PK\x03\x04")


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory) -> Path:
    """Two .tiny recordings holding the frames of a rendered flight (and nothing else in the folder)."""
    root = tmp_path_factory.mktemp("tiny")
    mcap = synth_recording(root / "office.mcap", "office", FRAMES, *GAUSSIAN, *HALF_SIZE)
    with open_recording(mcap, load_config(None, [])) as rec:
        frames = list(rec.frames())
    k = frames[0].intrinsics
    out = root / "flights"
    out.mkdir()
    for name in ("a", "b"):
        with open(out / f"{name}.tiny", "wb") as fh:  # np.savez adds .npz to a name without it
            np.savez(fh, rgb=np.stack([f.rgb for f in frames]), depth=np.stack([f.depth_m for f in frames]),
                     stamps=np.array([f.stamp_ns for f in frames]), K=np.array([k.fx, k.fy, k.cx, k.cy, k.width,
                                                                                 k.height]))
    return out


@pytest.mark.slow  # renders a flight and runs detect three times
def test_a_format_is_one_reader_and_one_registry_line(runner, tiny_dir: Path, tmp_path: Path, monkeypatch) -> None:
    flight = tiny_dir / "a.tiny"
    before = runner.invoke(main, ["info", str(flight)])
    assert before.exit_code == 1 and "unknown recording type '.tiny'" in before.stderr
    assert not safe_output.is_recording_file(flight)

    monkeypatch.setitem(formats.FORMATS, "tiny", TINY)  # the line

    info = runner.invoke(main, ["info", str(flight), "--json"])
    assert info.exit_code == 0, info.output + info.stderr
    assert json.loads(info.stdout)["format"] == "tiny" and json.loads(info.stdout)["frames"] == FRAMES
    assert recording_files(flight) == [flight]  # the rerun key reads the format's own file list
    assert safe_output.is_recording_file(flight)  # its magic: --force may replace it as a recording
    unknown = runner.invoke(main, ["info", str(_touch(tmp_path / "x.txt"))])
    assert "expected .bag, .mcap, .tiny, a ROS 2 bag folder or a TUM RGB-D folder" in unknown.stderr

    run = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(flight), "-o", str(run), *ODOMETRY])
    assert res.exit_code == 0, res.output + res.stderr
    assert json.loads((run / "landing.json").read_text())["status"] in ("site", "no_safe_site")
    run_json = json.loads((run / "run.json").read_text())
    assert run_json["summary"]["frames"] == FRAMES
    assert [e["path"] for e in run_json["key"]["inputs"]["recording"]] == [str(flight.resolve())]
    again = runner.invoke(main, ["detect", str(flight), "-o", str(run), *ODOMETRY])
    assert again.exit_code == 0 and "skipped" in (again.output + again.stderr).lower()  # the same key: a rerun

    runs = tmp_path / "runs"
    # one worker: in this process, where the line was added (a format in FORMATS' source reaches spawned workers)
    batch = runner.invoke(main, ["detect", str(tiny_dir / "*.tiny"), "-o", str(runs), "--workers", "1", *ODOMETRY])
    assert batch.exit_code == 0, batch.output + batch.stderr
    assert sorted(p.name for p in runs.iterdir() if p.is_dir()) == ["a", "b"]  # .tiny dropped from the run names


def test_a_bag_named_in_capitals_is_read_as_a_ros1_bag(tmp_path: Path) -> None:
    """The suffix is recognised in any case and the reader is told the format (it once guessed again from the
    suffix, in lower case only, and took ``X.BAG`` for a bag folder: "X.BAG/metadata.yaml: cannot read")."""
    path = _touch(tmp_path / "flight.BAG", b"not a bag at all")
    with pytest.raises(DatasetError, match=r"not a ROS 1 bag \(no '#ROSBAG V2.0' header\)"), \
            open_recording(path, load_config(None, [])):
        pass
