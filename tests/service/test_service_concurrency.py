"""20 concurrent submissions of small bakes: all complete, none runs twice, and identical
submissions racing each other collapse onto one job — embedded and scale-out modes."""

from __future__ import annotations

import re
from concurrent.futures import ThreadPoolExecutor

import pytest
from scenes import TINY_SPEC


def spec(seed: int) -> dict:
    return {**TINY_SPEC, "lights": {**TINY_SPEC["lights"], "seed": seed}}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["embedded", "postgres+redis"])
def test_twenty_concurrent_submissions(request, mode):
    # scale_out_env first, so that its database is dropped after the cluster is stopped.
    env = request.getfixturevalue("scale_out_env") if mode != "embedded" else {}
    c = request.getfixturevalue("make_cluster")(**env)
    c.start_api()
    c.start_worker("w1")
    c.start_worker("w2")
    # 20 different bakes and 6 copies of one more, all at once.
    work = [spec(i) for i in range(20)] + [spec(100)] * 6
    with ThreadPoolExecutor(len(work)) as pool:
        responses = list(pool.map(c.submit, work))
    assert all(r.status_code in (200, 202) for r in responses), [r.text for r in responses]
    ids = [r.json()["id"] for r in responses]
    assert len(set(ids[:20])) == 20
    assert len(set(ids[20:])) == 1 and ids[20] not in ids[:20]
    assert sum(r.status_code == 202 for r in responses[20:]) == 1
    jobs = [c.wait(i) for i in sorted(set(ids))]
    assert all(j["status"] == "succeeded" and j["attempts"] == 1 for j in jobs), jobs
    logs = c.log("w1") + c.log("w2")
    for job_id in set(ids):  # each job was claimed and run exactly once
        assert len(re.findall(f"job {job_id}: attempt", logs)) == 1, job_id
        assert sorted(p.name for p in c.job_dir(job_id).iterdir()) == [
            "bundle", "bundle.zip", "input"]
    listed = c.client.get("/v1/bakes", params={"status": "succeeded", "limit": 100}).json()
    assert len(listed["items"]) == 21
