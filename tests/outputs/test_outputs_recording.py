"""The recording writer: rosbag2 folders are byte-for-byte reproducible and name their own files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from sources_util import known_frame, pose, write_frames

from slzcli.config import load_config
from slzcli.outputs.recording import RecordingWriter
from slzcli.sources import open_recording


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("fmt", ["ros2-sqlite", "ros2-mcap"])
def test_same_frames_give_the_same_bag_bytes(tmp_path: Path, fmt: str) -> None:
    """Every file of the folder is identical across two writes to different places (sqlite included)."""
    a, b = tmp_path / "one" / "flight", tmp_path / "two" / "flight"
    for bag in (a, b):
        bag.parent.mkdir()
        with RecordingWriter(bag, fmt) as w:
            for i in range(3):
                w.write_frame(known_frame(i))
                w.write_pose("/slam/pose", known_frame(i).stamp_ns, pose(i))
    files_a, files_b = folder_bytes(a), folder_bytes(b)
    assert sorted(files_a) == ["flight." + ("db3" if fmt == "ros2-sqlite" else "mcap"), "metadata.yaml"]
    assert files_a == files_b
    # rosbag2 copies metadata.yaml into the storage file too: no temporary (per-process) name anywhere
    assert not [name for name, data in files_a.items() if b".tmp" in data or b".flight." in data]
    assert not [p for p in a.parent.iterdir() if p.name != "flight"]  # the staging folder is gone


@pytest.mark.parametrize("fmt", ["ros2-sqlite", "ros2-mcap"])
def test_metadata_names_the_files_in_the_folder(tmp_path: Path, fmt: str) -> None:
    bag = tmp_path / "bag2"
    frames = write_frames(bag, fmt, n=2)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    names = set(meta["relative_file_paths"]) | {f["path"] for f in meta.get("files", [])}
    assert names == {p.name for p in bag.iterdir() if p.name != "metadata.yaml"}
    assert ".tmp" not in (bag / "metadata.yaml").read_text()
    with open_recording(bag, load_config()) as rec:
        got = list(rec.frames())
    assert [g.stamp_ns for g in got] == [f.stamp_ns for f in frames]
    assert np.array_equal(got[1].rgb, frames[1].rgb)


def test_failed_bag_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), RecordingWriter(tmp_path / "bag", "ros2-mcap") as w:
        w.write_frame(known_frame(0))
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
