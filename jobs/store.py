"""The durable job table: the source of truth for every bake (README, Service).

One small interface (:class:`JobStore`) over SQLAlchemy Core, so the same statements run on
SQLite (embedded default) and PostgreSQL (``PRT_DATABASE_URL``). Core rather than raw
sqlite3/psycopg: one dialect-neutral statement set, connection pooling, and schema creation
for both back ends; no ORM, because every state change is a single conditional ``UPDATE``
whose row count says whether this process won (claiming a job, renewing a lease,
finishing), which is how two workers or a worker and the reaper never both act on a job.

States: ``queued`` → ``running`` → ``succeeded`` | ``failed`` | ``cancelled`` (a running job
whose lease expires, or whose attempt failed in a way worth retrying, goes back to
``queued`` until ``max_attempts`` is spent). The queue only carries job ids.

Times are epoch seconds (float) from the acting process's clock; machines are expected to
run NTP — leases are tens of seconds, far above clock skew.
"""

from __future__ import annotations

import functools
import json
import logging
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.engine import Connection, Engine

log = logging.getLogger("prtcore.store")


def transient_retry(fn: Callable) -> Callable:
    """Retry a store call on a dropped connection or a locked database (each call is one
    short transaction of conditional updates, so running it again is safe)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        for attempt in range(4):
            try:
                return fn(*args, **kwargs)
            except sa.exc.OperationalError as e:
                if attempt == 3:
                    raise
                log.warning("%s: transient database error, retrying: %s", fn.__name__,
                            str(e).splitlines()[0])
                time.sleep(0.2 * 2 ** attempt)
        raise AssertionError("unreachable")

    return wrapper


STATES = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL = ("succeeded", "failed", "cancelled")

metadata = sa.MetaData()

jobs = sa.Table(
    "prt_jobs", metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("status", sa.String(16), nullable=False),
    sa.Column("stage", sa.String(64)),
    sa.Column("progress", sa.Float, nullable=False, default=0.0),
    sa.Column("attempts", sa.Integer, nullable=False, default=0),
    sa.Column("max_attempts", sa.Integer, nullable=False),
    # Idempotency: sha256 over asset sha256 + spec sha256. ``active_key`` holds it while the
    # job is not failed/cancelled; its UNIQUE constraint makes concurrent identical
    # submissions collapse onto one job (NULLs are distinct in SQLite and PostgreSQL).
    sa.Column("content_key", sa.String(64), nullable=False),
    sa.Column("active_key", sa.String(64), unique=True),
    sa.Column("idempotency_key", sa.String(255), unique=True),
    # The asset as stored under ARTIFACTS/<id>/input/, and the name it was uploaded under
    # (sanitised; NULL for jobs created before it was kept).
    sa.Column("asset_name", sa.String(255), nullable=False),
    sa.Column("original_name", sa.String(255)),
    sa.Column("asset_sha256", sa.String(64), nullable=False),
    sa.Column("asset_bytes", sa.BigInteger, nullable=False),
    sa.Column("spec_json", sa.Text, nullable=False),
    sa.Column("spec_sha256", sa.String(64), nullable=False),
    sa.Column("lease_token", sa.String(32)),
    sa.Column("lease_expires", sa.Float),
    sa.Column("heartbeat_at", sa.Float),
    sa.Column("worker", sa.String(255)),
    sa.Column("cancel_requested", sa.Boolean, nullable=False, default=False),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("enqueued_at", sa.Float, nullable=False),
    sa.Column("started_at", sa.Float),
    sa.Column("finished_at", sa.Float),
    sa.Column("updated_at", sa.Float, nullable=False),
    sa.Column("timings_json", sa.Text, nullable=False, default="{}"),
    sa.Column("error_code", sa.String(64)),
    sa.Column("error_message", sa.Text),
    sa.Index("prt_jobs_status_created", "status", "created_at"),
    sa.Index("prt_jobs_created", "created_at", "id"),
)


@dataclass(frozen=True)
class Job:
    """One row of the job table."""

    id: str
    status: str
    stage: str | None
    progress: float
    attempts: int
    max_attempts: int
    content_key: str
    idempotency_key: str | None
    asset_name: str
    original_name: str | None
    asset_sha256: str
    asset_bytes: int
    spec_json: str
    spec_sha256: str
    lease_token: str | None
    lease_expires: float | None
    heartbeat_at: float | None
    worker: str | None
    cancel_requested: bool
    created_at: float
    enqueued_at: float
    started_at: float | None
    finished_at: float | None
    updated_at: float
    timings: dict[str, float]
    error_code: str | None
    error_message: str | None

    @classmethod
    def from_row(cls, row: Any) -> Job:
        d = dict(row._mapping)
        d.pop("active_key", None)
        d["timings"] = json.loads(d.pop("timings_json") or "{}")
        d["cancel_requested"] = bool(d["cancel_requested"])
        return cls(**d)


@dataclass(frozen=True)
class Claim:
    """A lease on a running job held by one worker."""

    job: Job
    token: str


def make_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite gets WAL, a busy timeout and foreign-key-free pragmas so
    the API and several worker processes can share one file."""
    if url.startswith("sqlite"):
        engine = sa.create_engine(url, connect_args={"timeout": 30, "check_same_thread": False},
                                  pool_pre_ping=False)

        @sa.event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record):  # pragma: no cover - trivial
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    return sa.create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=10)


class JobStore:
    """All reads and state changes of the job table."""

    def __init__(self, url: str, *, create: bool = True):
        self.url = url
        if url.startswith("sqlite:///"):
            from pathlib import Path

            Path(url[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
        self.engine = make_engine(url)
        if create:
            self.create_schema()

    def create_schema(self) -> None:
        # Several processes (API, workers) may start at once: a lost race to CREATE is
        # fine as long as the table is there afterwards.
        for attempt in range(5):
            try:
                metadata.create_all(self.engine)
                self._add_missing_columns()
                return
            except (sa.exc.IntegrityError, sa.exc.ProgrammingError, sa.exc.OperationalError):
                if attempt == 4:
                    raise
                time.sleep(0.2 * (attempt + 1))

    #: Columns added after the table was first released: a job table created by an older
    #: version gets them (nullable) when a process of this version opens it.
    ADDED_COLUMNS = ("original_name",)

    def _add_missing_columns(self) -> None:
        have = {c["name"] for c in sa.inspect(self.engine).get_columns(jobs.name)}
        for name in self.ADDED_COLUMNS:
            if name in have:
                continue
            col = jobs.c[name]
            ddl = col.type.compile(dialect=self.engine.dialect)
            with self._tx() as conn:  # a concurrent ALTER fails here; create_schema retries
                conn.execute(sa.text(f"ALTER TABLE {jobs.name} ADD COLUMN {name} {ddl}"))

    @contextmanager
    def _tx(self) -> Iterator[Connection]:
        with self.engine.begin() as conn:
            yield conn

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))

    # -- submission ------------------------------------------------------------------

    @transient_retry
    def find_active(self, content_key: str) -> Job | None:
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(jobs).where(jobs.c.active_key == content_key)).first()
        return Job.from_row(row) if row else None

    @transient_retry
    def find_by_idempotency_key(self, key: str) -> Job | None:
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(jobs).where(jobs.c.idempotency_key == key)).first()
        return Job.from_row(row) if row else None

    def create(self, *, content_key: str, idempotency_key: str | None, asset_name: str,
               asset_sha256: str, asset_bytes: int, spec_json: str, spec_sha256: str,
               max_attempts: int, job_id: str | None = None,
               original_name: str | None = None) -> tuple[Job, bool]:
        """Insert a queued job, or return the live job with the same content (or the same
        idempotency key). Returns ``(job, created)``."""
        now = time.time()
        job_id = job_id or uuid.uuid4().hex
        values = dict(id=job_id, status="queued", stage=None, progress=0.0, attempts=0,
                      max_attempts=max_attempts, content_key=content_key,
                      active_key=content_key, idempotency_key=idempotency_key,
                      asset_name=asset_name, original_name=original_name,
                      asset_sha256=asset_sha256, asset_bytes=asset_bytes,
                      spec_json=spec_json, spec_sha256=spec_sha256, cancel_requested=False,
                      created_at=now, enqueued_at=now, updated_at=now, timings_json="{}")
        try:
            with self._tx() as conn:
                conn.execute(jobs.insert().values(**values))
        except sa.exc.IntegrityError:
            existing = (self.find_by_idempotency_key(idempotency_key) if idempotency_key
                        else None) or self.find_active(content_key)
            if existing is None:  # the other row went final between insert and read
                return self.create(content_key=content_key, idempotency_key=idempotency_key,
                                   asset_name=asset_name, asset_sha256=asset_sha256,
                                   asset_bytes=asset_bytes, spec_json=spec_json,
                                   spec_sha256=spec_sha256, max_attempts=max_attempts,
                                   job_id=job_id, original_name=original_name)
            return existing, False
        return self.get(job_id), True  # type: ignore[return-value]

    def delete(self, job_id: str) -> None:
        """Remove a row (only used when the upload could not be stored after insert)."""
        with self._tx() as conn:
            conn.execute(jobs.delete().where(jobs.c.id == job_id))

    # -- reads -----------------------------------------------------------------------

    @transient_retry
    def get(self, job_id: str) -> Job | None:
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(jobs).where(jobs.c.id == job_id)).first()
        return Job.from_row(row) if row else None

    @transient_retry
    def list(self, *, status: str | None = None, limit: int = 50,
             before: tuple[float, str] | None = None) -> list[Job]:
        """Newest first; ``before`` is the (created_at, id) of the last item already seen."""
        q = sa.select(jobs).order_by(jobs.c.created_at.desc(), jobs.c.id.desc()).limit(limit)
        if status:
            q = q.where(jobs.c.status == status)
        if before is not None:
            t, i = before
            q = q.where(sa.or_(jobs.c.created_at < t,
                               sa.and_(jobs.c.created_at == t, jobs.c.id < i)))
        with self.engine.connect() as conn:
            return [Job.from_row(r) for r in conn.execute(q)]

    @transient_retry
    def counts(self) -> dict[str, int]:
        q = sa.select(jobs.c.status, sa.func.count()).group_by(jobs.c.status)
        with self.engine.connect() as conn:
            got = {s: int(n) for s, n in conn.execute(q)}
        return {s: got.get(s, 0) for s in STATES}

    def duration_histogram(self, buckets: tuple[float, ...]) -> tuple[list[int], int, float]:
        """Bake run time (first start → finish) of succeeded jobs: cumulative counts per
        bucket upper bound, total count and sum of seconds — one query, at scrape time."""
        d = jobs.c.finished_at - jobs.c.started_at
        cols = [sa.func.sum(sa.case((d <= b, 1), else_=0)) for b in buckets]
        q = sa.select(*cols, sa.func.count(), sa.func.sum(d)).where(
            jobs.c.status == "succeeded", jobs.c.started_at.is_not(None))
        with self.engine.connect() as conn:
            row = conn.execute(q).one()
        counts = [int(x or 0) for x in row[:len(buckets)]]
        return counts, int(row[-2] or 0), float(row[-1] or 0.0)

    # -- worker side -----------------------------------------------------------------

    def claim(self, job_id: str, worker: str, lease_s: float) -> Claim | None:
        """queued → running with a fresh lease; ``None`` if someone else has it, it is
        final, or its attempts are spent."""
        now = time.time()
        token = uuid.uuid4().hex
        with self._tx() as conn:
            n = conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id, jobs.c.status == "queued",
                       jobs.c.cancel_requested.is_(False),
                       jobs.c.attempts < jobs.c.max_attempts)
                .values(status="running", attempts=jobs.c.attempts + 1, lease_token=token,
                        lease_expires=now + lease_s, heartbeat_at=now, worker=worker,
                        started_at=sa.func.coalesce(jobs.c.started_at, now), updated_at=now,
                        stage=None, progress=0.0)
            ).rowcount
        if n != 1:
            return None
        return Claim(self.get(job_id), token)  # type: ignore[arg-type]

    @transient_retry
    def heartbeat(self, job_id: str, token: str, lease_s: float) -> tuple[bool, bool]:
        """Renew the lease. Returns ``(still_ours, cancel_requested)``."""
        now = time.time()
        return self._update_if_ours(job_id, token, lease_expires=now + lease_s,
                                    heartbeat_at=now)

    @transient_retry
    def progress(self, job_id: str, token: str, stage: str, progress: float,
                 timings: dict[str, float]) -> tuple[bool, bool]:
        """Publish stage/progress. Returns ``(still_ours, cancel_requested)``."""
        return self._update_if_ours(job_id, token, stage=stage, progress=progress,
                                    updated_at=time.time(), timings_json=json.dumps(timings))

    def _update_if_ours(self, job_id: str, token: str, **values) -> tuple[bool, bool]:
        """Set ``values`` on a running job only while ``token`` holds its lease, in one
        transaction. Returns ``(still_ours, cancel_requested)``."""
        with self._tx() as conn:
            n = conn.execute(
                jobs.update().where(jobs.c.id == job_id, jobs.c.lease_token == token,
                                    jobs.c.status == "running").values(**values)
            ).rowcount
            if n != 1:
                return False, False
            cancel = conn.execute(sa.select(jobs.c.cancel_requested)
                                  .where(jobs.c.id == job_id)).scalar_one()
        return True, bool(cancel)

    @transient_retry
    def finish(self, job_id: str, token: str, status: str, *, error_code: str | None = None,
               error_message: str | None = None, timings: dict[str, float] | None = None,
               ) -> bool:
        """running → succeeded / failed / cancelled, only by the lease holder."""
        assert status in FINAL
        now = time.time()
        values: dict[str, Any] = dict(status=status, finished_at=now, updated_at=now,
                                      lease_token=None, lease_expires=None,
                                      error_code=error_code, error_message=error_message)
        if status == "succeeded":
            values.update(progress=1.0, stage="done", error_code=None, error_message=None)
        else:
            values["active_key"] = None
        if timings is not None:
            values["timings_json"] = json.dumps(timings)
        with self._tx() as conn:
            n = conn.execute(jobs.update().where(jobs.c.id == job_id,
                                                 jobs.c.lease_token == token,
                                                 jobs.c.status == "running")
                             .values(**values)).rowcount
        return n == 1

    @transient_retry
    def retry_or_fail(self, job_id: str, token: str | None, error_code: str,
                      error_message: str) -> str | None:
        """After a failed attempt (``token`` given) or an expired lease (``token`` None):
        back to ``queued`` when attempts remain, else ``failed`` with the error. Returns the
        new status, or ``None`` if this process no longer owns the decision."""
        now = time.time()
        base = [jobs.c.id == job_id, jobs.c.status == "running"]
        if token is not None:
            base.append(jobs.c.lease_token == token)
        else:
            base.append(jobs.c.lease_expires < now)
        common = dict(lease_token=None, lease_expires=None, updated_at=now,
                      error_code=error_code, error_message=error_message)
        with self._tx() as conn:
            n = conn.execute(jobs.update().where(*base, jobs.c.cancel_requested.is_(True))
                             .values(status="cancelled", finished_at=now, active_key=None,
                                     **{**common, "error_code": "cancelled",
                                        "error_message": f"cancelled by request ({error_message})"}
                                     )).rowcount
            if n == 1:
                return "cancelled"
            n = conn.execute(jobs.update().where(*base, jobs.c.attempts < jobs.c.max_attempts)
                             .values(status="queued", enqueued_at=now, **common)).rowcount
            if n == 1:
                return "queued"
            n = conn.execute(jobs.update().where(*base)
                             .values(status="failed", finished_at=now, active_key=None,
                                     **common)).rowcount
        return "failed" if n == 1 else None

    @transient_retry
    def expired(self) -> list[str]:
        """Ids of running jobs whose lease has expired (their worker is gone)."""
        now = time.time()
        q = sa.select(jobs.c.id).where(jobs.c.status == "running", jobs.c.lease_expires < now)
        with self.engine.connect() as conn:
            return [r for (r,) in conn.execute(q)]

    def stale_queued(self, older_than_s: float) -> list[str]:
        """Queued jobs enqueued longer ago than ``older_than_s`` (their message may be
        lost); their ``enqueued_at`` is bumped so only one reaper re-sends each."""
        now = time.time()
        q = sa.select(jobs.c.id, jobs.c.enqueued_at).where(
            jobs.c.status == "queued", jobs.c.enqueued_at < now - older_than_s)
        out = []
        with self.engine.connect() as conn:
            rows = list(conn.execute(q))
        for job_id, t in rows:
            with self._tx() as conn:
                n = conn.execute(jobs.update().where(jobs.c.id == job_id,
                                                     jobs.c.status == "queued",
                                                     jobs.c.enqueued_at == t)
                                 .values(enqueued_at=now)).rowcount
            if n == 1:
                out.append(job_id)
        return out

    # -- cancel ----------------------------------------------------------------------

    @transient_retry
    def cancel(self, job_id: str) -> Job | None:
        """Queued → cancelled now; running → cancel requested (the worker stops at the next
        stage boundary). Final jobs are returned unchanged."""
        now = time.time()
        with self._tx() as conn:
            conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "queued")
                         .values(status="cancelled", cancel_requested=True, finished_at=now,
                                 updated_at=now, active_key=None))
            conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.status == "running")
                         .values(cancel_requested=True, updated_at=now))
        return self.get(job_id)
