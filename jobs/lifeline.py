"""Process lifetime: a supervised process dies with the process that supervises it.

``prtcore serve`` puts its pid in ``PRT_SUPERVISOR_PID`` for the processes it starts; each
calls :func:`die_with_supervisor` first thing. Two mechanisms, because each alone has a
hole:

* Linux ``prctl(PR_SET_PDEATHSIG)``: the kernel signals us the moment the parent goes, even
  after ``kill -9`` — but only if the parent was still there when we asked, and it fires
  when the parent *thread* that started us ends;
* a watchdog thread comparing ``getppid()`` with the supervisor's pid every ``interval``
  seconds: covers the race at start, other systems, and any case the first one misses.

A process that dies this way holds no lease for long: its job's lease expires and a
reaper sends the job to the next worker.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time

SUPERVISOR_ENV = "PRT_SUPERVISOR_PID"
_PR_SET_PDEATHSIG = 1


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel (Linux) to send ``sig`` to this process when its parent dies."""
    if not sys.platform.startswith("linux"):
        return False
    with contextlib.suppress(Exception):
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    return False


def _die(sig: int) -> None:
    os.kill(os.getpid(), sig)
    time.sleep(1.0)  # a catchable signal that was handled: leave anyway
    os._exit(1)


def die_with_parent(parent_pid: int | None = None, *, sig: int = signal.SIGKILL,
                    interval: float = 0.5) -> None:
    """From now on, this process dies (``sig``) when ``parent_pid`` (default: the current
    parent) is no longer its parent."""
    parent = parent_pid or os.getppid()
    set_parent_death_signal(sig)
    if os.getppid() != parent:  # gone before the kernel was asked
        _die(sig)

    def watch() -> None:
        while True:
            time.sleep(interval)
            if os.getppid() != parent:
                _die(sig)

    threading.Thread(target=watch, name="prtcore-lifeline", daemon=True).start()


def supervisor_pid() -> int | None:
    """The supervising ``prtcore serve`` process named in the environment, if any."""
    try:
        pid = int(os.environ.get(SUPERVISOR_ENV, ""))
    except ValueError:
        return None
    return pid if pid > 0 else None


def die_with_supervisor(sig: int = signal.SIGKILL) -> bool:
    """:func:`die_with_parent` when this process was started by a supervisor (and is not
    the supervisor itself). Returns whether it was."""
    pid = supervisor_pid()
    if pid is None or pid == os.getpid():
        return False
    die_with_parent(pid, sig=sig)
    return True
