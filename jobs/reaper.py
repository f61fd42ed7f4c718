"""The lease reaper: puts running jobs whose lease expired (their worker died) back in the
queue — or fails them when their attempts are spent — and re-sends queued jobs whose
message was lost.

Every worker runs one, and so does the ``prtcore serve`` supervisor, so that a job is reaped
even when no worker survives. Any number of reapers may run at once: each decision is a
conditional update of the job row (:meth:`jobs.store.JobStore.retry_or_fail` with no lease
token acts only on a ``running`` row whose lease has expired; ``stale_queued`` bumps
``enqueued_at`` conditionally), so exactly one reaper acts on a given expiry.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from .config import Settings
from .queue import enqueue
from .store import JobStore

log = logging.getLogger("prtcore.reaper")


def reap_once(settings: Settings, store: JobStore, huey: Any) -> list[tuple[str, str]]:
    """One reaper pass. Returns ``(job id, new status)`` for every job acted on."""
    acted = []
    for job_id in store.expired():
        status = store.retry_or_fail(job_id, None, "worker_lost",
                                     "the worker running this job stopped heartbeating "
                                     "(lease expired)")
        if status is None:  # another reaper (or the worker itself) got there first
            continue
        acted.append((job_id, status))
        log.warning("job %s: lease expired → %s", job_id, status)
        if status == "queued":
            enqueue(job_id, huey)
    for job_id in store.stale_queued(settings.requeue_after_s):
        enqueue(job_id, huey)
        acted.append((job_id, "resent"))
    return acted


class Reaper(threading.Thread):
    """Runs :func:`reap_once` every ``reaper_interval_s`` until :meth:`stop`."""

    def __init__(self, settings: Settings, store: JobStore, huey: Any,
                 name: str = "prtcore-reaper"):
        super().__init__(name=name, daemon=True)
        self.settings, self.store, self.huey = settings, store, huey
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.wait(self.settings.reaper_interval_s):
            try:
                reap_once(self.settings, self.store, self.huey)
            except Exception:  # keep reaping through transient database errors
                log.exception("reaper pass failed")

    def stop(self, timeout: float | None = 5.0) -> None:
        self._stop_event.set()
        if self.is_alive():
            self.join(timeout)
