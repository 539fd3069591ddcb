"""The repo's docs stand on their own: cited METHOD sections exist, the landing.json contract
covers what a real run writes, every link resolves, every `slz` command shown parses (the cheap
ones run), and the site builds without a warning."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
from typing import Any

import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, REPO

from slzcli.cli import main

DOCS = REPO / "docs"
README = REPO / "README.md"
# "METHOD 2.3", "METHOD.md 2.3.1", "[docs/METHOD.md](docs/METHOD.md) 2.5", "METHOD 2.6-2.9"
SECTION_CITE = re.compile(r"METHOD(?:\.md)?\)?\s+(\d+(?:\.\d+)+)(?:\s*-\s*(\d+(?:\.\d+)+))?")
# 'METHOD "A consistent derivation"', 'DESIGN.md "Run folder"'
NAMED_CITE = re.compile(r"\b(METHOD|BASELINE|DESIGN)(?:\.md)?\s+\"([^\"]+)\"")
HEADING = re.compile(r"^#+\s+(.*)$", re.MULTILINE)
TABLE_KEY = re.compile(r"^\|\s*`([A-Za-z0-9_.]+)`\s*\|", re.MULTILINE)


def cited_texts() -> list[tuple[str, str]]:
    """(file, text) of every file whose comments cite the docs: the package's code and config, the README."""
    paths = sorted((REPO / "slzcli").rglob("*.py")) + sorted((REPO / "slzcli").rglob("*.yaml")) + [README]
    return [(str(p.relative_to(REPO)), p.read_text(encoding="utf-8")) for p in paths]


def expand(first: str, last: str | None) -> list[str]:
    """'2.6', '2.9' -> 2.6, 2.7, 2.8, 2.9 (a range over the last component)."""
    if last is None:
        return [first]
    head, lo = first.rsplit(".", 1)
    head2, hi = last.rsplit(".", 1)
    assert head == head2, f"range {first}-{last} spans two parents"
    return [f"{head}.{k}" for k in range(int(lo), int(hi) + 1)]


def cited_sections(text: str) -> set[str]:
    return {s for m in SECTION_CITE.finditer(text) for s in expand(m.group(1), m.group(2))}


def heading_numbers(markdown: str) -> set[str]:
    return {h.split()[0].rstrip(".") for h in HEADING.findall(markdown) if re.match(r"\d+(\.\d+)*\.?\s", h + " ")}


def missing_sections(texts: list[tuple[str, str]], method_md: str) -> list[str]:
    have = heading_numbers(method_md)
    return sorted({f"{name}: METHOD {s}" for name, text in texts for s in cited_sections(text) if s not in have})


def test_the_citation_pattern_finds_sections_and_ranges() -> None:
    assert cited_sections("see METHOD 2.6-2.9 and METHOD.md 2.3.1; [docs/METHOD.md](docs/METHOD.md) 2.5") == {
        "2.6", "2.7", "2.8", "2.9", "2.3.1", "2.5"}
    assert missing_sections([("x.py", "METHOD 7.7")], "## 2.1 Points\n") == ["x.py: METHOD 7.7"]


def test_every_cited_method_section_is_a_heading_of_docs_method() -> None:
    texts = cited_texts()
    cited = set().union(*(cited_sections(t) for _, t in texts))
    # what the code cites today; guards against a pattern that silently finds nothing
    assert {"2.1", "2.2", "2.3", "2.3.1", "2.3.2", "2.4", "2.5", "2.6", "2.9"} <= cited, cited
    assert missing_sections(texts, (DOCS / "METHOD.md").read_text(encoding="utf-8")) == []


def test_every_named_section_cited_is_a_heading_of_that_doc() -> None:
    headings = {name: [h.lower() for h in HEADING.findall((DOCS / f"{name}.md").read_text(encoding="utf-8"))]
                for name in ("METHOD", "BASELINE", "DESIGN")}
    cites = [(f, m.group(1), m.group(2)) for f, text in cited_texts() for m in NAMED_CITE.finditer(text)]
    assert cites, "no named citation found (the code cites 'METHOD \"A consistent derivation\"')"
    missing = [f"{f}: {doc} \"{title}\"" for f, doc, title in cites
               if not any(title.lower() in h for h in headings[doc])]
    assert missing == []


# ----------------------------------------------------------------------------- landing.json contract
def contract_rows() -> dict[str, str]:
    """The landing.json table of docs/DESIGN.md: key path -> its whole row."""
    design = (DOCS / "DESIGN.md").read_text(encoding="utf-8")
    section = design.split("## landing.json", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        m = TABLE_KEY.match(line)
        if m:
            rows[m.group(1)] = line
    return rows


def undocumented(record: dict[str, Any], rows: dict[str, str]) -> list[str]:
    """Key paths of ``record`` that the contract does not name: a path is documented by its own row, an
    object by rows of its members, and a key below a documented object by its name in backticks in the
    nearest documented parent's row."""
    out = []

    def walk(obj: dict[str, Any], prefix: str) -> None:
        for key, value in obj.items():
            path = f"{prefix}{key}"
            grouped = isinstance(value, dict) and any(r.startswith(path + ".") for r in rows)  # rows of its members
            if path not in rows and not grouped:
                parent = prefix.rstrip(".")
                while parent and parent not in rows:
                    parent = parent.rpartition(".")[0]
                if not parent or f"`{key}`" not in rows[parent]:
                    out.append(path)
                    continue
            if isinstance(value, dict):
                walk(value, path + ".")

    walk(record, "")
    return out


def test_undocumented_finds_a_missing_key() -> None:
    rows = {"a": "| `a` |", "b": "| `b` | | | has `c` |", "g.h": "| `g.h` |"}
    record = {"a": 1, "b": {"c": 1, "d": 2}, "e": 3, "g": {"h": 1, "i": 2}}
    assert undocumented(record, rows) == ["b.d", "e", "g.i"]


@pytest.fixture(scope="module")
def landing_records(tmp_path_factory) -> dict[str, dict[str, Any]]:
    """landing.json of a real run with a site (parking_lot from 5 m) and of one without (no_site)."""
    folder = tmp_path_factory.mktemp("docs")
    runner = CliRunner()
    out = {}
    for scene, extra in (("parking_lot", ("--start", "0,0,5")), ("no_site", ())):
        bag, run = folder / f"{scene}.mcap", folder / f"{scene}_run"
        res = runner.invoke(main, ["synth", scene, "-o", str(bag), "--frames", "3", *extra, *GAUSSIAN])
        assert res.exit_code == 0, res.output
        res = runner.invoke(main, ["detect", str(bag), "-o", str(run)])
        assert res.exit_code == 0, res.output
        out[scene] = json.loads((run / "landing.json").read_text())
    return out


def test_every_key_a_run_writes_to_landing_json_is_in_the_contract(landing_records) -> None:
    assert landing_records["parking_lot"]["status"] == "site", landing_records["parking_lot"].get("reason")
    assert landing_records["no_site"]["status"] == "no_safe_site"
    rows = contract_rows()
    assert {"status", "site", "site.corners_world", "timings_ms"} <= set(rows), sorted(rows)
    for scene, record in landing_records.items():
        top = [k for k in record if k not in rows]
        assert top == [], f"{scene}: top-level keys not in docs/DESIGN.md: {top}"
        assert undocumented(record, rows) == [], scene


# ----------------------------------------------------------------------------- README links
def test_readme_links_to_docs_resolve_and_nothing_points_outside_the_repo() -> None:
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\((docs/[^)#\s]+)", text)
    assert {"docs/METHOD.md", "docs/BASELINE.md", "docs/DESIGN.md"} <= set(targets), targets
    assert [t for t in targets if not (REPO / t).is_file()] == []
    assert "../shared" not in text
    bare = [m.group(0) for m in re.finditer(r"(?<!docs/)\b(METHOD|BASELINE|DESIGN)\.md", text)]
    assert bare == [], f"README names docs without their docs/ path: {bare}"


def test_links_between_docs_resolve() -> None:
    broken = []
    for doc in sorted(DOCS.glob("*.md")):
        for target in re.findall(r"\]\(([^)#\s]+)", doc.read_text(encoding="utf-8")):
            if "://" not in target and not (doc.parent / target).exists():
                broken.append(f"{doc.name}: {target}")
    assert broken == []


def test_readme_links_resolve_and_it_stays_a_start_page() -> None:
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    targets = [t for t in re.findall(r"\]\(([^)#\s]+)", text) if "://" not in t]
    assert "docs/img/overlay.jpg" in targets and "docs/USAGE.md" in targets
    assert [t for t in targets if not (REPO / t).exists()] == []
    assert not re.search(r"\bissue \d+", text, re.I)  # internal history belongs to git, not the start page


# ----------------------------------------------------------------------------- commands shown
SHOWN = re.compile(r"^\s*(?:\$\s*)?(slz\s[^#\n]*)", re.MULTILINE)
TABLE_EXAMPLE = re.compile(r"^\|.*\|\s*`(slz\s[^`]+)`\s*\|\s*$", re.MULTILINE)  # a table's example column


def shown_commands() -> list[tuple[str, str]]:
    """(file, command line) of every ``slz ...`` line in a code block of README and docs/, and of every
    example in a table's last column (README's command table). Mentions in prose are not commands."""
    out = []
    for path in [README, *sorted(DOCS.glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
        lines = [m.group(1) for b in blocks for m in SHOWN.finditer(b)]
        lines += TABLE_EXAMPLE.findall(re.sub(r"```.*?```", "", text, flags=re.S))
        out += [(path.name, ln.strip()) for ln in lines]
    return out


def parse_only(line: str) -> None:
    """Parse ``line`` as the CLI would (options, choices, callbacks), without running the command."""
    import click

    args = shlex.split(line)[1:]
    cmd: click.Command = main
    # The chain of contexts the CLI builds: a sub-command's settings (help option names, ...) come from its
    # parents, and click caches a command's help option on first use, so a context without them would
    # change --help for every later test.
    ctx = main.context_class(main, info_name="slz", **main.context_settings)
    while isinstance(cmd, click.Group) and args and not args[0].startswith("-"):
        sub = cmd.get_command(ctx, args[0])
        assert sub is not None, f"no command {args[0]!r} in: {line}"
        ctx = click.Context(sub, info_name=args[0], parent=ctx)
        cmd, args = sub, args[1:]
    cmd.make_context(ctx.info_name, list(args), parent=ctx.parent, resilient_parsing=False).close()


# The shapes docs write that are not runnable lines (placeholders, usage summaries, pieces of a sentence).
PLACEHOLDER = re.compile(r"\b[A-Z]+\b|\.\.\.|\[|\||<|[A-Z]+=")


def test_every_slz_command_shown_in_readme_and_docs_parses() -> None:
    """Each concrete command line (no placeholder like BAG or RUN) goes through the CLI's own parser:
    an option renamed or removed, a bad choice or value fails here. Running all of them would render
    and detect for minutes; the cheap ones run in the next test."""
    import click
    from click.exceptions import Exit

    shown = shown_commands()
    concrete = [(f, c) for f, c in shown if not PLACEHOLDER.search(c)]
    assert len(concrete) >= 15, concrete  # the README alone shows more: a pattern that finds nothing fails
    failed = []
    for f, c in shown:  # usage summaries (`slz detect BAG... [-o RUN]`): at least the command exists
        cmd: click.Command | None = main
        for word in shlex.split(c)[1:]:
            if not isinstance(cmd, click.Group) or not word.islower() or word.startswith("-"):
                break
            cmd = cmd.get_command(main.context_class(cmd, **main.context_settings), word)
            if cmd is None:
                failed.append(f"{f}: {c}: no command {word!r}")
                break
    for f, c in concrete:
        try:
            parse_only(c)
        except Exit:
            pass  # --help, --version
        except Exception as err:  # every kind of parse failure is reported together
            failed.append(f"{f}: {c}: {type(err).__name__}: {err}")
    assert failed == []


CHEAP = ("slz synth --list", "slz config dump --profile paper", "slz --help")


@pytest.mark.parametrize("line", CHEAP)
def test_cheap_commands_shown_run(line: str) -> None:
    assert any(c.startswith(line) for _, c in shown_commands()), f"{line} is no longer shown"
    res = CliRunner().invoke(main, shlex.split(line)[1:])
    assert res.exit_code == 0, res.output


def test_the_docs_site_builds_without_warnings(tmp_path) -> None:
    """`make docs`' build (mkdocs --strict: a broken link, an anchor or a page left out of nav fails)."""
    mkdocs = shutil.which("mkdocs") or shutil.which("mkdocs", path=str(REPO / ".venv" / "bin"))
    if mkdocs is None:
        import sys
        from pathlib import Path

        candidate = Path(sys.executable).parent / "mkdocs"
        mkdocs = str(candidate) if candidate.is_file() else None
    if mkdocs is None:
        pytest.skip("mkdocs not installed (pip install -e '.[docs]')")
    res = subprocess.run([mkdocs, "build", "--strict", "-d", str(tmp_path / "site"), "-f", str(REPO / "mkdocs.yml")],
                         capture_output=True, text=True, env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"},
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert "WARNING" not in res.stderr
    assert (tmp_path / "site" / "index.html").is_file() and (tmp_path / "site" / "USAGE" / "index.html").is_file()
