"""torchnav.memory: glibc malloc set to keep big freed blocks for reuse (opt-in, process-wide)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

PROBE = """
import sys, torch
from torchnav.memory import freed_memory_held, hold_freed_memory
def rss_mib():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
if sys.argv[1] == "hold":
    assert hold_freed_memory() and hold_freed_memory() and freed_memory_held()  # set once; a second call is a no-op
else:
    assert not freed_memory_held()
x = torch.ones(64 << 18)  # 64 MiB, touched
before = rss_mib()
del x
print(before - rss_mib())  # MiB given back to the OS by the free
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc's malloc only")
def test_held_memory_stays_with_the_process_for_reuse():
    given_back = {}
    for mode in ("system", "hold"):
        out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True)
        given_back[mode] = float(out.stdout.strip())
    assert given_back["system"] > 50  # a block this big is mapped for itself and unmapped when freed
    assert given_back["hold"] < 8  # kept in the heap, to serve the next step's temporaries
