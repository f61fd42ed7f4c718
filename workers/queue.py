"""The one queue module, imported by the API (to enqueue) and the workers (to consume).

huey carries job ids only; the job table (:mod:`service.store`) is the source of truth, so
a lost, duplicated or late message is harmless: a worker claims a job with a conditional
update and drops messages for jobs that are not ``queued``.

Back end from the settings: a SQLite huey queue at ``DATA_DIR/queue.db`` by default,
Redis when ``PRT_QUEUE_URL=redis://...``.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from huey import RedisHuey, SqliteHuey

from service.config import Settings, get_settings

TASK_NAME = "prtcore.bake"


def make_huey(settings: Settings) -> Any:
    url = settings.queue_url
    if url and url.startswith(("redis://", "rediss://", "unix://")):
        huey = RedisHuey(settings.queue_name, url=url, results=False, utc=True,
                         blocking=True, read_timeout=1)
    elif url and not url.startswith("sqlite:///"):
        raise ValueError(f"PRT_QUEUE_URL: unsupported scheme in {url!r} "
                         "(expected redis://... or sqlite:///path)")
    else:
        path = url[len("sqlite:///"):] if url else str(settings.data_dir / "queue.db")
        from pathlib import Path

        Path(path).parent.mkdir(parents=True, exist_ok=True)
        huey = SqliteHuey(settings.queue_name, filename=path, results=False, utc=True,
                          timeout=30)

    @huey.task(name=TASK_NAME)
    def bake(job_id: str) -> None:
        from .runner import run_job

        run_job(job_id)

    huey.bake_task = bake
    return huey


@lru_cache(maxsize=1)
def get_huey() -> Any:
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
