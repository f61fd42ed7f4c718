"""prtcore/core/memory.py: freed arena memory goes back to the OS."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from prtcore.core.memory import _libc_trim, release_free_memory

CHILD = r"""
import threading
import numpy as np
from prtcore.core.memory import release_free_memory

def rss_mib():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024

pinned = []


def work():  # 64 KiB arrays (below glibc's mmap threshold): the thread's own arena
    keep = [np.ones(1 << 13) for _ in range(6400)]
    pinned.append(keep[-1])  # the arena's top stays in use: it cannot shrink from there
    keep.clear()


t = threading.Thread(target=work)
t.start()
t.join()
before = rss_mib()
released = release_free_memory()
print(before, rss_mib(), released)
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                    reason="malloc_trim is glibc's")
def test_a_worker_threads_freed_arrays_leave_the_process():
    assert _libc_trim() is not None
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True).stdout.split()
    before, after, released = float(out[0]), float(out[1]), out[2] == "True"
    assert released and before - after > 200, (before, after)


def test_release_is_safe_to_call_anywhere():
    assert isinstance(release_free_memory(), bool)
