"""Failure modes with real processes: kill -9 of a worker mid-bake, API restart mid-bake,
a bake that crashes every attempt, cancel (queued and running), an unwritable artifact
location, the per-job time limit."""

from __future__ import annotations

import shutil
import time

import pytest
from scenes import TINY_SPEC
from service_harness import SLOW_SPEC, alive, running_mid_bake, single_bundle


#: Stages strictly inside a bake (after intake, before the bundle is written).
@pytest.mark.slow
def test_kill9_worker_mid_bake_job_still_succeeds_once(make_cluster):
    c = make_cluster()
    c.start_api()
    c.start_worker("w1")
    job_id = c.submit(SLOW_SPEC).json()["id"]
    c.wait(job_id, running_mid_bake)
    c.kill("w1")  # SIGKILL to the worker's process group, bake included
    assert c.job(job_id)["status"] == "running"  # nobody has noticed yet
    c.start_worker("w2")
    job = c.wait(job_id)
    assert job["status"] == "succeeded", job
    assert job["attempts"] == 2
    single_bundle(c, job_id)
    assert "attempt 2 of 3" in c.log("w2")
    assert "attempt 1" not in c.log("w2")


@pytest.mark.slow
def test_kill9_of_the_worker_process_alone_takes_its_bake_down(make_cluster):
    """Only the worker's pid is killed (its forkserver and bake are not signalled): the bake
    notices at once (lifeline pipe) and dies instead of writing on without a lease."""
    c = make_cluster()
    c.start_api()
    c.start_worker("w1")
    job_id = c.submit(SLOW_SPEC).json()["id"]
    c.wait(job_id, running_mid_bake)
    kids = c.kill_pid_only("w1")
    assert kids, "the worker had no bake process"
    deadline = time.monotonic() + 30
    while alive(kids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(kids), "bake processes outlived their worker"
    c.start_worker("w2")
    job = c.wait(job_id)
    assert job["status"] == "succeeded" and job["attempts"] == 2, job
    single_bundle(c, job_id)


@pytest.mark.slow
def test_restarting_the_api_mid_bake_loses_nothing(make_cluster):
    c = make_cluster()
    c.start_api()
    c.start_worker()
    job_id = c.submit(SLOW_SPEC).json()["id"]
    c.wait(job_id, running_mid_bake)
    c.kill("api")
    c.start_api()
    job = c.wait(job_id)
    assert job["status"] == "succeeded" and job["attempts"] == 1, job
    single_bundle(c, job_id)


def test_a_bake_that_crashes_every_attempt_ends_failed(make_cluster):
    c = make_cluster(PRT_MAX_ATTEMPTS="2")
    c.start_api()
    c.start_worker(PRT_FAULT_CRASH_STAGE="texels")
    job_id = c.submit(TINY_SPEC).json()["id"]
    job = c.wait(job_id)
    assert job["status"] == "failed", job
    assert job["attempts"] == 2 and job["max_attempts"] == 2
    assert job["error"]["code"] == "bake_crashed"
    assert "signal 9" in job["error"]["message"] and "attempt 2 of 2" in job["error"]["message"]
    assert not (c.job_dir(job_id) / "bundle").exists()
    # A failed job's content may be submitted again: a new job, not the failed one.
    again = c.submit(TINY_SPEC)
    assert again.status_code == 202 and again.json()["id"] != job_id


def test_cancel_a_queued_and_a_running_bake(make_cluster):
    c = make_cluster()
    c.start_api()
    queued = c.submit(TINY_SPEC).json()["id"]
    r = c.client.delete(f"/v1/bakes/{queued}")
    assert r.status_code == 202 and r.json()["status"] == "cancelled"
    running = c.submit(SLOW_SPEC).json()["id"]
    c.start_worker()
    c.wait(running, lambda j: j["status"] == "running")
    r = c.client.delete(f"/v1/bakes/{running}")
    assert r.status_code == 202 and r.json()["cancel_requested"] is True
    job = c.wait(running)
    assert job["status"] == "cancelled", job
    assert job["error"]["code"] == "cancelled"
    assert not (c.job_dir(running) / "bundle").exists()
    assert c.job(queued)["status"] == "cancelled" and c.job(queued)["attempts"] == 0
    assert c.client.delete(f"/v1/bakes/{running}").json()["status"] == "cancelled"
    assert c.client.get(f"/v1/bakes/{running}/artifacts").status_code == 409


def test_unwritable_artifact_location_fails_with_a_clear_error(make_cluster):
    """The job's folder in the artifact location is replaced by a file before a worker gets
    to it (root ignores permission bits, so a file stands in for a read-only mount)."""
    c = make_cluster()
    c.start_api()
    job_id = c.submit(TINY_SPEC).json()["id"]
    d = c.job_dir(job_id)
    shutil.rmtree(d)
    d.write_text("not a folder")
    c.start_worker()
    job = c.wait(job_id, timeout=60)
    assert job["status"] == "failed" and job["attempts"] == 1, job
    assert job["error"]["code"] == "artifacts_unwritable"
    assert "artifact location not writable" in job["error"]["message"]
    assert job_id in job["error"]["message"]


def test_time_limit_fails_the_job(make_cluster):
    c = make_cluster(PRT_JOB_TIME_LIMIT_S="1")
    c.start_api()
    c.start_worker()
    job_id = c.submit(SLOW_SPEC).json()["id"]
    job = c.wait(job_id)
    assert job["status"] == "failed" and job["error"]["code"] == "time_limit", job
    assert not (c.job_dir(job_id) / "bundle").exists()
