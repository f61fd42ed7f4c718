"""Scale-out mode: PostgreSQL job store + Redis queue, two workers (separate processes,
as if on two machines sharing the artifact location)."""

from __future__ import annotations

import pytest
from scenes import TINY_SPEC
from service_harness import SLOW_SPEC, running_mid_bake, single_bundle


def test_postgres_redis_end_to_end(scale_out_env, make_cluster):
    c = make_cluster(**scale_out_env)
    c.start_api()
    ready = c.client.get("/readyz").json()
    assert ready["checks"] == {"database": "ok", "queue": "ok"}
    assert not (c.data / "jobs.db").exists() and not (c.data / "queue.db").exists()
    c.start_worker("w1")
    c.start_worker("w2")
    r = c.submit(TINY_SPEC)
    assert r.status_code == 202
    job_id = r.json()["id"]
    job = c.wait(job_id)
    assert job["status"] == "succeeded" and job["attempts"] == 1, job
    assert c.submit(TINY_SPEC).json()["id"] == job_id
    single_bundle(c, job_id)
    z = c.client.get(f"/v1/bakes/{job_id}/artifacts/bundle.zip")
    assert z.status_code == 200 and z.content[:2] == b"PK"
    assert c.client.get(f"/v1/bakes/{job_id}/report").status_code == 200
    metrics = c.client.get("/metrics").text
    assert 'prtcore_jobs{state="succeeded"} 1.0' in metrics
    assert "prtcore_queue_depth 0.0" in metrics
    # Exactly one worker ran it.
    logs = c.log("w1") + c.log("w2")
    assert logs.count(f"job {job_id}: attempt") == 1


@pytest.mark.slow
def test_postgres_redis_kill9_worker_mid_bake(scale_out_env, make_cluster):
    c = make_cluster(**scale_out_env)
    c.start_api()
    c.start_worker("w1")
    job_id = c.submit(SLOW_SPEC).json()["id"]
    c.wait(job_id, running_mid_bake)
    c.kill("w1")
    c.start_worker("w2")
    job = c.wait(job_id)
    assert job["status"] == "succeeded" and job["attempts"] == 2, job
    single_bundle(c, job_id)
