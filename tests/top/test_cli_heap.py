"""The CLI's allocator setting: a frame's arrays and a recording's messages come from the kept heap.

Setting glibc's trim threshold turns off its own raising of the mmap threshold; left at 128 KiB, every block
larger than that (each image, message and map) is mmapped once the kept heap's pad is used up, and faulted in
afresh (the info pass over a 300-frame 848 KB-a-frame recording: 308,000 page faults and 1.2 s, against 5,500 and
0.54 s). The count of mmapped blocks is read from glibc's malloc_info, in a fresh interpreter.
"""

from __future__ import annotations

import ctypes.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
glibc = pytest.mark.skipif(not sys.platform.startswith("linux") or ctypes.util.find_library("c") is None,
                           reason="glibc's mallopt and malloc_info")

PROBE = r"""
import ctypes, ctypes.util, os, re, sys, tempfile
sys.path.insert(0, sys.argv[1])
libc = ctypes.CDLL(ctypes.util.find_library("c"))
if sys.argv[2] == "cli":
    from slzcli.cli import _keep_heap_warm
    _keep_heap_warm()
else:  # the setting without the mmap threshold
    libc.mallopt(-2, 64 << 20)
    libc.mallopt(-1, 128 << 20)
import numpy as np
libc.fopen.restype = ctypes.c_void_p
def mmapped():
    fd, path = tempfile.mkstemp()
    os.close(fd)
    f = libc.fopen(path.encode(), b"w")
    libc.malloc_info(0, ctypes.c_void_p(f))
    libc.fclose(ctypes.c_void_p(f))
    text = open(path).read()
    os.unlink(path)
    return int(re.findall(r'<total type="mmap" count="(\d+)"', text)[-1])
before = mmapped()
live = [np.ones((480, 848), np.float32) for _ in range(100)]   # 160 MB alive: beyond the 64 MiB pad
print(mmapped() - before)
"""


def _mmapped(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", PROBE, str(ROOT), mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@glibc
def test_large_blocks_come_from_the_heap_once_the_cli_set_the_allocator() -> None:
    assert _mmapped("cli") == 0
    # the probe tells: without the mmap threshold, blocks beyond the pad are mmapped (61 of 100 measured)
    assert _mmapped("trim only") > 10
