"""Fixtures of the service tests: an in-process app (TestClient) for the API contract, and
real API + worker processes (:mod:`service_harness`) for end-to-end behaviour."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from service_harness import Cluster  # noqa: E402


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)
    return rep


@pytest.fixture
def make_cluster(tmp_path, request):
    """``make_cluster(**env)`` → a :class:`Cluster` (nothing started); all its processes are
    killed (process groups) at teardown, whatever the test did; their logs are printed
    when the test failed."""
    made: list[Cluster] = []

    def make(**env: str) -> Cluster:
        c = Cluster(tmp_path / f"cluster{len(made)}", **env)
        made.append(c)
        return c

    yield make
    failed = getattr(getattr(request.node, "rep_call", None), "failed", False)
    for c in made:
        c.close()
        if failed:
            for log in sorted(c.logs.glob("*.log")):
                print(f"--- {log.name}\n{c.log(log.stem)}")


@pytest.fixture
def app_client(tmp_path, monkeypatch):
    """A TestClient of the app with its own data folder and no worker (jobs stay queued).
    ``app_client(**settings)`` to override settings."""
    from fastapi.testclient import TestClient

    from jobs.config import Settings
    from service.main import create_app

    opened = []

    def make(**kw):
        kw.setdefault("data_dir", tmp_path / "data")
        settings = Settings(**kw)
        client = TestClient(create_app(settings), raise_server_exceptions=True)
        client.__enter__()
        client.settings = settings
        opened.append(client)
        return client

    yield make
    for c in opened:
        c.__exit__(None, None, None)


@pytest.fixture
def scale_out_env():
    """PRT_* variables for scale-out mode: a fresh PostgreSQL database (dropped afterwards)
    and a fresh Redis queue name (flushed afterwards) on this machine's servers, which
    scripts/services.sh starts. Unreachable servers fail the test, they do not skip it.
    Request it before ``make_cluster`` so the processes stop before the database goes."""
    import uuid

    import psycopg
    import redis

    name = "prt_" + uuid.uuid4().hex[:12]
    admin = "postgresql://postgres@127.0.0.1:5432/postgres"
    r = redis.Redis.from_url("redis://127.0.0.1:6379/0")
    try:
        psycopg.connect(admin, connect_timeout=5).close()
        r.ping()
    except (psycopg.OperationalError, redis.ConnectionError):
        # Not up (e.g. plain `pytest` on a machine just booted): start them as
        # scripts/test.sh does, then let any remaining failure fail the test.
        import subprocess

        subprocess.run(["bash", str(HERE.parents[1] / "scripts" / "services.sh")],
                       check=False, timeout=120)
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    r.ping()
    env = {"PRT_DATABASE_URL": f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}",
           "PRT_QUEUE_URL": "redis://127.0.0.1:6379/0", "PRT_QUEUE_NAME": name}
    yield env
    for key in r.scan_iter(match=f"*{name}*"):
        r.delete(key)
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
