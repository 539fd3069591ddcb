"""outputs/output_dir.py: a folder an older slz wrote (no ``slz_output`` in its marker), known by its keys."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from slzcli.outputs import output_dir


def _older_compare(folder: Path, doc: Mapping[str, object], names: tuple[str, ...]) -> None:
    folder.mkdir(exist_ok=True)
    (folder / "compare.json").write_text(json.dumps(doc))
    for name in names:
        (folder / name).write_text("x")


def test_an_older_compare_folder_names_its_recordings_and_variants_and_nothing_else(tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    doc = {"methods": ["fuzzy"], "config_hash": "h", "recordings": [{"name": "f1"}, "not an object"],
           "variant_table": [{"recording": "f1"}, 3]}
    _older_compare(out, doc, ("compare.csv", "f1", "variants_f1.png", "notes.txt"))
    got = output_dir.inspect(out, output_dir.COMPARE)
    assert got.finished
    assert set(got.names) == {"compare.json", "compare.csv", "f1", "variants_f1.png"}  # the user's notes are not slz's


def test_an_older_compare_marker_with_null_lists_gives_its_fixed_files(tmp_path: Path) -> None:
    # JSON null (or any non-list) where the lists were: the fixed names only, not a crash on iterating None
    out = tmp_path / "cmp"
    _older_compare(out, {"methods": [], "config_hash": "h", "recordings": None, "variant_table": {"f1": 1}},
                   ("compare.csv", "f1"))
    got = output_dir.inspect(out, output_dir.COMPARE)
    assert set(got.names) == {"compare.json", "compare.csv"}
