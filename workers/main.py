"""``prtcore worker``: a huey consumer running bakes, plus the lease reaper.

Start as many as needed, on as many machines as needed (same ``PRT_DATABASE_URL``,
``PRT_QUEUE_URL`` and a shared ``PRT_ARTIFACTS_DIR``). Each runs ``PRT_CONCURRENCY`` bakes at
once. The reaper, in every worker, puts running jobs whose lease expired (their worker
died) back in the queue — or fails them when their attempts are spent — and re-sends queued
jobs whose message was lost; conditional updates make sure only one reaper acts on a job.
"""

from __future__ import annotations

import logging
import threading

from service.config import Settings, get_settings

log = logging.getLogger("prtcore.worker")


def reap_once(settings: Settings, store, huey) -> list[tuple[str, str]]:
    """One reaper pass. Returns ``(job id, new status)`` for every job acted on."""
    from .queue import enqueue

    acted = []
    for job_id in store.expired():
        status = store.retry_or_fail(job_id, None, "worker_lost",
                                     "the worker running this job stopped heartbeating "
                                     "(lease expired)")
        if status is None:
            continue
        acted.append((job_id, status))
        log.warning("job %s: lease expired → %s", job_id, status)
        if status == "queued":
            enqueue(job_id, huey)
    for job_id in store.stale_queued(settings.requeue_after_s):
        enqueue(job_id, huey)
        acted.append((job_id, "resent"))
    return acted


def _reaper(settings: Settings, store, huey, stop: threading.Event) -> None:
    while not stop.wait(settings.reaper_interval_s):
        try:
            reap_once(settings, store, huey)
        except Exception:  # keep reaping through transient database errors
            log.exception("reaper pass failed")


def run_worker(settings: Settings | None = None) -> None:
    """Consume the queue until SIGINT (graceful) or SIGTERM."""
    from huey.consumer import Consumer

    from .queue import get_huey
    from .runner import _context, get_store

    settings = settings or get_settings()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    store = get_store()
    huey = get_huey()
    _context()  # start the forkserver (prtcore preloaded) before the first bake
    stop = threading.Event()
    t = threading.Thread(target=_reaper, args=(settings, store, huey, stop), daemon=True,
                         name="prtcore-reaper")
    t.start()
    consumer = Consumer(huey, workers=max(1, settings.concurrency), worker_type="thread",
                        periodic=False, initial_delay=0.05, backoff=1.3,
                        max_delay=settings.poll_max_delay_s, check_worker_health=True)
    try:
        consumer.run()
    finally:
        stop.set()
