"""The queue, producer side, imported by the API (to enqueue) and the workers (to re-send).

huey carries job ids only; the job table (:mod:`jobs.store`) is the source of truth, so a
lost, duplicated or late message is harmless: a worker claims a job with a conditional
update and drops messages for jobs that are not ``queued``.

The consumer side lives in :mod:`workers`: it builds its queue with
``make_huey(settings, handler=run_job)``; the task is registered under the same name either
way, so a producer's message is understood by the consumer, and this module needs nothing
from the workers.

Back end from the settings: a SQLite huey queue at ``DATA_DIR/queue.db`` by default,
Redis when ``PRT_QUEUE_URL=redis://...``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

from huey import RedisHuey, SqliteHuey

from .config import Settings, get_settings

TASK_NAME = "prtcore.bake"


def _producer_only(job_id: str) -> None:
    raise RuntimeError(f"job {job_id}: this queue was opened to send, not to run bakes "
                       "(run `prtcore worker`)")


def make_huey(settings: Settings, handler: Callable[[str], Any] | None = None) -> Any:
    """A huey instance for the configured back end with the bake task registered.

    ``handler(job_id)`` runs a message on the consumer side; a producer passes none."""
    url = settings.queue_url
    if url and url.startswith(("redis://", "rediss://", "unix://")):
        huey = RedisHuey(settings.queue_name, url=url, results=False, utc=True,
                         blocking=True, read_timeout=1)
    elif url and not url.startswith("sqlite:///"):
        raise ValueError(f"PRT_QUEUE_URL: unsupported scheme in {url!r} "
                         "(expected redis://... or sqlite:///path)")
    else:
        path = url[len("sqlite:///"):] if url else str(settings.data_dir / "queue.db")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        huey = SqliteHuey(settings.queue_name, filename=path, results=False, utc=True,
                          timeout=30)
    run = handler or _producer_only

    # Defined here, in this module, on both sides: huey names a task by module + name.
    @huey.task(name=TASK_NAME)
    def bake(job_id: str) -> None:
        run(job_id)

    huey.bake_task = bake
    return huey


@lru_cache(maxsize=1)
def get_huey() -> Any:
    """The process's producer queue (from the environment's settings)."""
    return make_huey(get_settings())


def enqueue(job_id: str, huey: Any = None) -> None:
    """Send a job id to the workers."""
    (huey or get_huey()).bake_task(job_id)


def queue_depth(huey: Any = None) -> int:
    return int((huey or get_huey()).pending_count())


def ping(huey: Any = None) -> None:
    """Raise if the queue back end cannot be reached."""
    h = huey or get_huey()
    storage = h.storage
    if hasattr(storage, "conn") and hasattr(storage.conn, "ping"):
        storage.conn.ping()
    else:
        storage.queue_size()
