"""The import layers of slzcli (issue 17), read from the source with ``ast``, not by importing it.

Every ``import`` and ``from ... import`` of an slzcli module counts, wherever it stands: at
module level, inside a function, or under ``if TYPE_CHECKING`` (a type is a dependency too).
A function-level import used to hide the cycle pipeline -> outputs.run_folder -> pipeline.

The rules, one line each (``RULES``: importing package -> packages it must not import):

- outputs/ is a leaf of the detection path: it serialises what it is handed and computes no
  result, so it imports no package that computes one (nor the commands above it).
- evaluate/ measures results against ground truth; it does not write files nor run detection.
- scoring/, terrain/, landing/ are the per-frame steps: pure functions of arrays, they import
  neither the run machinery nor the writers nor each other's callers.
- slam/ tracks frames; it knows nothing of the detection steps above it (it may use the file
  helpers of outputs/, a leaf, to store a downloaded vocabulary).
- sources/ reads recordings; it knows nothing of what is done with the frames.
- control/ simulates the landing from a site; it does not import detection or the writers.
- methods/ are the detection methods (plug-ins of the run): they use the per-frame steps, never
  the run machinery that runs them nor the writers; the steps below do not import them (only
  config reads ``methods.registry``, a leaf, for the names).
- summary (what a run sums up to) does not import the run machinery that calls it; pipeline
  (the run assembly) does not import the commands built on it (compare, batch, cli).
- Only ``slzcli.cli`` may import ``slzcli.cli`` (``FORBIDDEN_FOR_ALL``).
- No import cycle among slzcli modules, counting every import (``test_no_cycle``); the ground floor
  (``GROUND``: types, records, errors, version, pinhole, methods.registry) imports nothing of slzcli above it.
- Imports stand at module top: at most ``MAX_FUNCTION_LEVEL`` import statements of slzcli inside a
  function outside the entry points (cli, api), a ceiling lowered as they move.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / "slzcli"

DETECTION = ("pipeline", "summary", "compare", "batch", "methods")  # the run machinery and the methods it runs
COMMANDS = ("cli", "api")  # the entry points: the command line and the Python API
RULES: dict[str, tuple[str, ...]] = {
    # package: packages (slzcli.<name>, module or subpackage) it must not import
    "outputs": ("pipeline", "summary", "evaluate", "landing", "slam", "terrain", "control", "compare", "batch",
                "scoring", "synth", "cli"),
    "evaluate": (*DETECTION, "outputs", "landing", "scoring", "control", *COMMANDS),
    "scoring": (*DETECTION, "outputs", "evaluate", "landing", "slam", "control", "synth", *COMMANDS),
    "terrain": (*DETECTION, "outputs", "evaluate", "landing", "slam", "control", "synth", *COMMANDS),
    "landing": (*DETECTION, "outputs", "evaluate", "slam", "control", "synth", *COMMANDS),
    "slam": (*DETECTION, "evaluate", "landing", "scoring", "terrain", "control", "synth", *COMMANDS),
    "sources": (*DETECTION, "outputs", "evaluate", "landing", "scoring", "terrain", "slam", "control", "synth",
                *COMMANDS),
    "control": (*DETECTION, "outputs", "evaluate", "scoring", "terrain", "slam", "synth", *COMMANDS),
    "methods": ("pipeline", "summary", "compare", "batch", "outputs", "evaluate", "control", "synth", *COMMANDS),
    "summary": ("pipeline", "compare", "batch", "methods", *COMMANDS),
    "pipeline": ("compare", "batch", *COMMANDS),
}
FORBIDDEN_FOR_ALL = ("cli",)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[str, int, bool]]:
    """(imported slzcli module, line, at module level) for every import statement in one file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    top_level = {id(n) for n in tree.body}
    out: list[tuple[str, int, bool]] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Import | ast.ImportFrom):
            continue
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            base = node.module or ""
            if node.level:  # relative import
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            # ``from slzcli import pipeline`` imports the module slzcli.pipeline
            names = [f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base for a in node.names]
        out += [(n, node.lineno, id(node) in top_level) for n in dict.fromkeys(names)
                if n == "slzcli" or n.startswith("slzcli.")]
    return out


def _is_module(name: str) -> bool:
    rel = Path(*name.split("."))
    return (ROOT.parent / rel).with_suffix(".py").is_file() or (ROOT.parent / rel / "__init__.py").is_file()


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}
IMPORTS = {m: imports_of(p) for m, p in MODULES.items()}


def _top(name: str) -> str:
    """slzcli.outputs.run_folder -> outputs; slzcli -> ''."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_the_parser_sees_every_kind_of_import() -> None:
    """The rules below mean something only if the parser finds imports of every form."""
    found = {(m, n) for m, rows in IMPORTS.items() for n, _, _ in rows}
    assert ("slzcli.cli", "slzcli.pipeline") in found  # function-level, in a command
    assert ("slzcli.methods.base", "slzcli.types") in found  # under TYPE_CHECKING
    assert len(MODULES) > 80


@pytest.mark.parametrize("package", sorted(RULES))
def test_layer_rules(package: str) -> None:
    bad = [f"{m}:{line} imports {n}" for m, rows in IMPORTS.items() if _top(m) == package
           for n, line, _ in rows if _top(n) in RULES[package]]
    assert not bad, "\n".join(bad)


def test_only_cli_imports_cli() -> None:
    bad = [f"{m}:{line} imports {n}" for m, rows in IMPORTS.items() if _top(m) not in FORBIDDEN_FOR_ALL
           for n, line, _ in rows if _top(n) in FORBIDDEN_FOR_ALL]
    assert not bad, "\n".join(bad)


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of a directed graph (depth-first search), or None."""
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(v: str) -> list[str] | None:
        colour[v] = 1
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if colour.get(w) == 1:
                return [*stack[stack.index(w):], w]
            if w not in colour and (found := visit(w)) is not None:
                return found
        stack.pop()
        colour[v] = 2
        return None

    for v in sorted(graph):
        if v not in colour and (found := visit(v)) is not None:
            return found
    return None


def test_no_cycle() -> None:
    """No cycle among modules through any import: module level, inside a function or under ``TYPE_CHECKING``
    (a package's __init__ is its own module)."""
    graph = {m: {n for n, _, _ in rows if n in MODULES and n != m} for m, rows in IMPORTS.items()}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def test_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


BACKEND_NAMES = {"recorded", "orbslam3", "odometry"}


def test_backends_are_told_apart_by_capability_not_by_name() -> None:
    """Outside slam/ no code compares a value with a backend's name (``SlamBackend`` capabilities instead)."""
    bad = []
    for m, path in MODULES.items():
        if _top(m) == "slam":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                consts = {c.value for c in (node.left, *node.comparators) if isinstance(c, ast.Constant)}
                if consts & BACKEND_NAMES:
                    bad.append(f"{m}:{node.lineno}")
    assert not bad, bad


METHOD_NAMES = {"fuzzy", "bayes", "px4slp"}
RUN_MACHINERY = ("pipeline", "summary", "compare", "batch")


def test_the_run_machinery_asks_no_method_its_name() -> None:
    """The run (pipeline/, summary, compare, batch) tells methods apart by what they say of themselves
    (``methods.base.Method``), never by comparing a name; nor by ``isinstance`` on a method's class."""
    method_classes = {"MapMethod", "GridMethod", "FuzzyScorer", "BayesScorer", "Px4SlpPlanner"}
    bad = []
    for m, path in MODULES.items():
        if _top(m) not in RUN_MACHINERY:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                consts = {c.value for c in (node.left, *node.comparators) if isinstance(c, ast.Constant)}
                if consts & METHOD_NAMES:
                    bad.append(f"{m}:{node.lineno} compares with a method name")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance" \
                    and {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} & method_classes:
                bad.append(f"{m}:{node.lineno} isinstance on a method")
    assert not bad, bad


GROUND = {"slzcli.types": {"slzcli.records"}, "slzcli.records": set(),
          "slzcli.errors": set(), "slzcli.version": set(), "slzcli.pinhole": {"slzcli.types"},
          "slzcli.methods.registry": set()}


def test_the_ground_floor_names_nothing_above_it() -> None:
    """The modules every layer names (the frozen types, errors, the version, the pinhole check, the method
    registry) import nothing of slzcli but each other, not even for a type."""
    bad = [f"{m} imports {n}" for m, allowed in GROUND.items() for n, _, _ in IMPORTS[m]
           if n not in allowed and n != "slzcli.methods"]
    assert not bad, bad



ENTRY_POINTS = ("slzcli.cli", "slzcli.api")  # they import the run lazily on purpose (start-up time, no numpy)
MAX_FUNCTION_LEVEL = 20  # import statements of slzcli inside a function outside ENTRY_POINTS: lower it as they move


def function_imports(tree: ast.AST) -> list[int]:
    """The lines of the import statements of slzcli (absolute or relative) inside a function body."""
    lines: set[int] = set()
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            for node in ast.walk(fn):
                if (isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("slzcli"))) \
                        or (isinstance(node, ast.Import) and any(a.name.startswith("slzcli") for a in node.names)):
                    lines.add(node.lineno)
    return sorted(lines)


def test_function_imports_finds_every_form() -> None:
    src = ("import slzcli.types\nfrom slzcli import errors\n"
           "def f():\n    import numpy\n    from slzcli import x\n    from . import y\n"
           "    def g():\n        import slzcli.z\n")
    assert function_imports(ast.parse(src)) == [5, 6, 8]


def test_function_level_imports_stay_few() -> None:
    """An import belongs at module top; one inside a function hides a dependency (and used to hide a cycle)."""
    found = [f"{m}:{line}" for m, path in MODULES.items() if m not in ENTRY_POINTS
             for line in function_imports(ast.parse(path.read_text()))]
    assert len(found) <= MAX_FUNCTION_LEVEL, "\n".join(found)
