"""The job table's state machine, in process on SQLite: atomic claims, leases held only by
their holder, the reaper's requeue-or-fail, lost-message resends, idempotent creation."""

from __future__ import annotations

import time

import pytest

from jobs.config import Settings
from jobs.queue import make_huey
from jobs.reaper import reap_once
from jobs.store import JobStore


@pytest.fixture
def env(tmp_path):
    settings = Settings(data_dir=tmp_path, max_attempts=2, requeue_after_s=0.0)
    store = JobStore(settings.db_url)
    huey = make_huey(settings)
    yield settings, store, huey
    store.engine.dispose()


def new_job(store, key="k1", idem=None):
    return store.create(content_key=key, idempotency_key=idem, asset_name="asset.glb",
                        asset_sha256="a" * 64, asset_bytes=1, spec_json="{}",
                        spec_sha256="s" * 64, max_attempts=2)


def test_create_is_idempotent_by_content_and_key(env):
    _, store, _ = env
    job, created = new_job(store)
    assert created and job.status == "queued"
    again, created = new_job(store)
    assert not created and again.id == job.id
    other, created = new_job(store, key="k2", idem="i")
    assert created and other.id != job.id
    same_key, created = new_job(store, key="k3", idem="i")
    assert not created and same_key.id == other.id


def test_claim_is_exclusive_and_only_the_holder_finishes(env):
    _, store, _ = env
    job, _ = new_job(store)
    claim = store.claim(job.id, "w1", lease_s=30)
    assert claim is not None and claim.job.attempts == 1 and claim.job.status == "running"
    assert store.claim(job.id, "w2", lease_s=30) is None
    assert store.heartbeat(job.id, "not-the-token", 30) == (False, False)
    assert store.heartbeat(job.id, claim.token, 30) == (True, False)
    assert not store.finish(job.id, "not-the-token", "succeeded")
    store.cancel(job.id)
    assert store.heartbeat(job.id, claim.token, 30) == (True, True)  # cancel requested
    assert store.finish(job.id, claim.token, "succeeded")
    assert store.get(job.id).status == "succeeded"
    assert not store.finish(job.id, claim.token, "failed")  # final stays final


def test_reaper_requeues_an_expired_lease_then_fails_when_attempts_are_spent(env):
    settings, store, huey = env
    settings = settings.model_copy(update={"requeue_after_s": 3600.0})
    job, _ = new_job(store)
    assert store.claim(job.id, "w1", lease_s=-1.0) is not None  # already expired
    assert reap_once(settings, store, huey) == [(job.id, "queued")]
    assert huey.pending_count() == 1
    j = store.get(job.id)
    assert j.status == "queued" and j.error_code == "worker_lost" and j.attempts == 1
    assert store.claim(job.id, "w2", lease_s=-1.0).job.attempts == 2
    assert reap_once(settings, store, huey) == [(job.id, "failed")]
    j = store.get(job.id)
    assert j.status == "failed" and j.attempts == 2 and "lease expired" in j.error_message
    assert store.claim(job.id, "w3", lease_s=30) is None
    assert reap_once(settings, store, huey) == []


def test_a_live_lease_is_left_alone(env):
    settings, store, huey = env
    settings = settings.model_copy(update={"requeue_after_s": 3600.0})
    job, _ = new_job(store)
    store.claim(job.id, "w1", lease_s=60)
    assert reap_once(settings, store, huey) == []
    assert store.get(job.id).status == "running"


def test_lost_messages_are_resent_once(env):
    settings, store, huey = env
    job, _ = new_job(store)
    time.sleep(0.01)
    assert reap_once(settings, store, huey) == [(job.id, "resent")]
    settings = settings.model_copy(update={"requeue_after_s": 3600.0})
    assert reap_once(settings, store, huey) == []  # enqueued_at was bumped


def test_cancel_requested_on_a_dead_workers_job_ends_cancelled(env):
    settings, store, huey = env
    job, _ = new_job(store)
    store.claim(job.id, "w1", lease_s=-1.0)
    store.cancel(job.id)
    assert reap_once(settings, store, huey) == [(job.id, "cancelled")]
    j = store.get(job.id)
    assert j.status == "cancelled" and j.error_code == "cancelled"
    again, created = new_job(store)  # its content may be baked again
    assert created and again.id != job.id


def test_a_job_table_of_the_previous_version_gets_the_new_columns(tmp_path):
    """original_name (issue 14) is added, nullable, to a table created without it; the
    rows already there read back with None."""
    import sqlalchemy as sa

    from jobs.store import jobs

    url = f"sqlite:///{tmp_path / 'old.db'}"
    engine = sa.create_engine(url)
    old = sa.MetaData()
    sa.Table(jobs.name, old, *[sa.Column(c.name, c.type, primary_key=c.primary_key)
                               for c in jobs.columns if c.name != "original_name"])
    old.create_all(engine)
    engine.dispose()
    store = JobStore(url)
    job, created = store.create(content_key="k", idempotency_key=None, asset_name="asset.glb",
                                asset_sha256="a" * 64, asset_bytes=1, spec_json="{}",
                                spec_sha256="s" * 64, max_attempts=2, original_name="duck.glb")
    assert created and store.get(job.id).original_name == "duck.glb"
    JobStore(url)  # opening again is a no-op
    store.engine.dispose()
