"""``prtcore worker``: a huey consumer running bakes, plus the lease reaper.

Start as many as needed, on as many machines as needed (same ``PRT_DATABASE_URL``,
``PRT_QUEUE_URL`` and a shared ``PRT_ARTIFACTS_DIR``). Each runs ``PRT_CONCURRENCY`` bakes at
once. The reaper (:mod:`jobs.reaper`), in every worker, puts running jobs whose lease
expired (their worker died) back in the queue — or fails them when their attempts are
spent — and re-sends queued jobs whose message was lost; conditional updates make sure only
one reaper acts on a job. A worker started by ``prtcore serve`` dies with it
(:mod:`jobs.lifeline`).
"""

from __future__ import annotations

import logging

from jobs import lifeline
from jobs.config import Settings, get_settings
from jobs.queue import make_huey
from jobs.reaper import Reaper

from .runner import get_store, run_job, start_forkserver

log = logging.getLogger("prtcore.worker")


def make_consumer_huey(settings: Settings):
    """The queue with this process's task handler: each message runs one attempt."""
    return make_huey(settings, handler=lambda job_id: run_job(job_id))


def run_worker(settings: Settings | None = None) -> None:
    """Consume the queue until SIGINT (graceful) or SIGTERM."""
    from huey.consumer import Consumer

    supervised = lifeline.die_with_supervisor()
    settings = settings or get_settings()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if supervised:
        log.info("supervised by process %s: exiting when it does", lifeline.supervisor_pid())
    store = get_store()
    huey = make_consumer_huey(settings)
    start_forkserver()  # prtcore preloaded before the first bake
    reaper = Reaper(settings, store, huey)
    reaper.start()
    consumer = Consumer(huey, workers=max(1, settings.concurrency), worker_type="thread",
                        periodic=False, initial_delay=0.05, backoff=1.3,
                        max_delay=settings.poll_max_delay_s, check_worker_health=True)
    try:
        consumer.run()
    finally:
        reaper.stop()
