"""Handing freed heap memory back to the operating system.

glibc's malloc gives each thread that allocates its own arena. Arrays below the mmap
threshold (which grows to 32 MiB as large arrays are freed) that worker threads allocate
and free stay in those arenas, and the main thread's later allocations do not reuse them:
after a stage that ran numpy on worker threads (the gather's batches) the process holds
that memory until the end of the bake (0.4 GiB at the 1024² Cornell bake). ``malloc_trim``
returns the free pages of every arena.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _libc_trim():
    """glibc's ``malloc_trim``, or None (another C library, or none found)."""
    name = ctypes.util.find_library("c")
    if not name:
        return None
    try:
        fn = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_size_t]
    fn.restype = ctypes.c_int
    return fn


def release_free_memory() -> bool:
    """Return the free pages of every malloc arena to the OS (glibc ``malloc_trim(0)``).
    True when glibc did release memory; False when it had none to release or the C
    library has no such call."""
    fn = _libc_trim()
    return bool(fn(0)) if fn is not None else False
