"""``prtcore serve``: the API (uvicorn) and supervised worker processes on one machine.

Embedded defaults need no external server (SQLite job store and queue, artifacts under
``PRT_DATA_DIR``). The workers are separate processes — bakes never run in the API process —
started as ``python -m prtcore worker`` with the same environment, and stopped with it.

Nothing is left stuck when a process dies:

* a worker that exits is restarted by the :class:`Supervisor`, after a delay that doubles
  from ``PRT_RESTART_BACKOFF_S`` up to ``PRT_RESTART_BACKOFF_MAX_S`` (reset once a worker
  has stayed up ``PRT_RESTART_RESET_AFTER_S``), so a worker that cannot start does not spin;
* this process runs the lease reaper too (:mod:`jobs.reaper`), so a job whose worker died
  goes back to the queue (or fails, its attempts spent) even when no worker is up; reapers
  act through conditional updates, so it and the workers' reapers never both act on a job;
* the workers (and API processes of ``--api-workers N``) die with this process, ``kill -9``
  included (:mod:`jobs.lifeline`), so no orphan holds the queue; their bakes die with them.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

from jobs.config import Settings, get_settings
from jobs.lifeline import SUPERVISOR_ENV

log = logging.getLogger("prtcore.serve")


@dataclass
class _Slot:
    index: int
    proc: subprocess.Popen | None = None
    started: float = 0.0
    delay: float = 0.0
    restart_at: float = 0.0
    restarts: int = 0


class Supervisor(threading.Thread):
    """Starts ``count`` worker processes and keeps them running until :meth:`stop`.

    Every process is started from this thread, and this thread lives until they have been
    stopped: Linux delivers a child's parent-death signal when the *thread* that started it
    ends."""

    POLL_S = 0.2

    def __init__(self, settings: Settings, count: int, env: dict[str, str],
                 argv: list[str] | None = None):
        super().__init__(name="prtcore-supervisor", daemon=True)
        self.settings, self.env = settings, env
        self.argv = argv or [sys.executable, "-m", "prtcore", "worker"]
        self.slots = [_Slot(i, delay=settings.restart_backoff_s) for i in range(max(0, count))]
        self._stop_event = threading.Event()
        self.started_event = threading.Event()

    # -- the loop ----------------------------------------------------------------------

    def run(self) -> None:
        try:
            for slot in self.slots:
                self._start(slot)
            self.started_event.set()
            while not self._stop_event.wait(self.POLL_S):
                try:
                    self._check(time.monotonic())
                except Exception:  # never let the supervisor die of one bad pass
                    log.exception("supervisor pass failed")
        finally:
            self.started_event.set()
            self._stop_all()

    def _start(self, slot: _Slot) -> None:
        try:
            slot.proc = subprocess.Popen(self.argv, env=self.env)
        except OSError as e:
            log.error("worker %d: could not start: %s", slot.index, e)
            slot.proc = None
            self._schedule(slot, time.monotonic())
            return
        slot.started = time.monotonic()
        log.info("worker %d: started (pid %d)", slot.index, slot.proc.pid)

    def _schedule(self, slot: _Slot, now: float) -> None:
        slot.restart_at = now + slot.delay
        slot.delay = min(slot.delay * 2.0, self.settings.restart_backoff_max_s)

    def _check(self, now: float) -> None:
        for slot in self.slots:
            if slot.proc is None:
                if now >= slot.restart_at:
                    slot.restarts += 1
                    self._start(slot)
                continue
            code = slot.proc.poll()
            if code is None:
                continue
            up = now - slot.started
            if up >= self.settings.restart_reset_after_s:
                slot.delay = self.settings.restart_backoff_s
            why = f"signal {-code}" if code < 0 else f"status {code}"
            log.warning("worker %d (pid %d) exited (%s) after %.1f s; restarting in %.1f s",
                        slot.index, slot.proc.pid, why, up, slot.delay)
            slot.proc = None
            self._schedule(slot, now)

    # -- stopping ----------------------------------------------------------------------

    def _stop_all(self, grace_s: float = 20.0) -> None:
        procs = [s.proc for s in self.slots if s.proc is not None]
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for p in procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()

    def stop(self, timeout: float = 30.0) -> None:
        self._stop_event.set()
        if self.is_alive():
            self.join(timeout)

    def pids(self) -> list[int]:
        return [s.proc.pid for s in self.slots if s.proc is not None and s.proc.poll() is None]


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1,
          api_workers: int = 1) -> int:
    import uvicorn

    from jobs.queue import make_huey
    from jobs.reaper import Reaper
    from jobs.store import JobStore

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    # What the workers and API processes inherit: the same data folder, and our pid so
    # that they die with us.
    os.environ.setdefault("PRT_DATA_DIR", str(settings.data_dir.resolve()))
    os.environ[SUPERVISOR_ENV] = str(os.getpid())
    # uvicorn shuts down gracefully on SIGTERM, restores this handler and re-raises the
    # signal: turn it into a normal exit so the workers below are stopped too.
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    store = JobStore(settings.db_url)
    reaper = Reaper(settings, store, make_huey(settings), name="prtcore-serve-reaper")
    reaper.start()
    supervisor = Supervisor(settings, workers, env=dict(os.environ))
    supervisor.start()
    try:
        uvicorn.run("service.main:app_factory", factory=True, host=host, port=port,
                    workers=api_workers, log_level="info", access_log=False)
    finally:
        supervisor.stop()
        reaper.stop()
        store.engine.dispose()
    return 0


def _exit_on_sigterm(_sig: int, _frame: object) -> None:
    raise SystemExit(0)
