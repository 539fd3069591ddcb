"""The CLI's exit: the garbage collector's objects are frozen after every other exit handler, so the
interpreter's finalisation does not traverse them (a process setting of the entry point, not of the library)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# an exit handler registered before the CLI's runs after it (the last registered runs first)
PROBE = r"""
import atexit, gc, sys
sys.path.insert(0, sys.argv[1])
atexit.register(lambda: print("frozen at exit:", gc.get_freeze_count() > 0))
from slzcli.cli import main
main(sys.argv[2:], standalone_mode=False)
print("frozen in the command:", gc.get_freeze_count() > 0)
"""


def _lines(*args: str) -> list[str]:
    proc = subprocess.run([sys.executable, "-c", PROBE, str(ROOT), *args], capture_output=True, text=True,
                          timeout=120, check=True)
    return proc.stdout.strip().splitlines()[-2:]


def test_a_command_freezes_the_collector_only_at_exit() -> None:
    assert _lines("config", "dump", "--json") == ["frozen in the command: False", "frozen at exit: True"]

