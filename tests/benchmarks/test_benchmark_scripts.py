"""benchmarks/: every script says what it measures and takes its arguments, machine block and results path from
benchmarks/harness.py (one shape of results for every benchmark); the harness writes what it promises."""

from __future__ import annotations

import ast
import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
SCRIPTS = sorted(BENCHMARKS.glob("*.py"))
# what the harness does for a script: its own copies of it are what the rule is for
BOILERPLATE = {("argparse", "ArgumentParser"): "its own argument parser (harness.parser)",
               ("sys.path", "insert"): "its own sys.path entries (harness.use_test_helpers)",
               ("platform", "python_version"): "its own machine block (harness.machine via write_results)"}


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), str(path))


def _is_script(tree: ast.Module) -> bool:
    return any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)


def _imports_harness(tree: ast.Module) -> bool:
    return any((isinstance(n, ast.Import) and any(a.name == "harness" for a in n.names))
               or (isinstance(n, ast.ImportFrom) and n.module == "harness") for n in ast.walk(tree))


def _calls(tree: ast.Module) -> set[tuple[str, str]]:
    return {(ast.unparse(n.func.value), n.func.attr) for n in ast.walk(tree)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)}


def test_the_benchmarks_are_found() -> None:
    assert len(SCRIPTS) > 20 and BENCHMARKS / "harness.py" in SCRIPTS


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_every_benchmark_file_says_what_it_is(path: Path) -> None:
    doc = ast.get_docstring(_tree(path))
    assert doc and len(doc.split()) >= 5, f"{path.name}: a docstring that says what it measures and how to run it"


@pytest.mark.parametrize("path", [p for p in SCRIPTS if p.name != "harness.py"], ids=lambda p: p.name)
def test_every_benchmark_script_runs_on_the_harness(path: Path) -> None:
    tree = _tree(path)
    if _is_script(tree):
        assert _imports_harness(tree), f"{path.name} does not import benchmarks/harness.py"
    own = [what for call, what in BOILERPLATE.items() if call in _calls(tree)]
    assert not own, f"{path.name} has {', '.join(own)}"
    own_path = [n for n in ast.walk(tree) if isinstance(n, ast.BinOp) and isinstance(n.op, ast.Div)
                and isinstance(n.right, ast.Constant) and n.right.value == "results"]
    assert not own_path, f"{path.name} builds its own results path (harness.results_path or --out)"


@pytest.fixture
def harness(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """benchmarks/harness.py loaded as a benchmark loads it, its sys.path changes undone afterwards."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    spec = importlib.util.spec_from_file_location("harness", BENCHMARKS / "harness.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_parser_describes_the_script_and_writes_to_its_results_file(harness: ModuleType) -> None:
    ap = harness.parser("Frames per second of a reader.\n\nUsage: read.py [--runs N]", "read")
    assert ap.description == "Frames per second of a reader."
    assert "Usage: read.py" in ap.format_help()
    assert ap.parse_args([]).out == BENCHMARKS / "results" / "read.json"
    assert ap.parse_args(["--out", "x.json"]).out == Path("x.json")
    assert not hasattr(harness.parser(None, "fusion_decorrelation", out=False).parse_args([]), "out")


def test_results_are_strict_json_with_one_machine_block(harness: ModuleType, tmp_path: Path) -> None:
    out = tmp_path / "sub" / "bench.json"
    harness.write_results(out, {"rows": [{"ms": float("nan"), "fps": float("inf"), "n": 3}], "where": tmp_path})
    doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"bare {c} in the JSON"))
    assert doc["rows"] == [{"ms": None, "fps": None, "n": 3}] and doc["where"] == str(tmp_path)
    assert set(doc["machine"]) >= {"python", "platform", "cpu", "cores", "load_avg", "numpy", "opencv"}
    assert [p.name for p in out.parent.iterdir()] == ["bench.json"]   # no temporary file left


def test_test_helpers_and_the_checkout_are_importable_from_a_benchmark(harness: ModuleType) -> None:
    harness.use_test_helpers()
    assert str(harness.TESTS) in sys.path and str(harness.REPO) in sys.path
    assert (harness.TESTS / "landing_file.py").is_file()
