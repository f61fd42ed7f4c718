"""`prtcore serve` keeps going when its processes die (issue 14), with real processes.

``kill -9`` of the worker, of the bake process, of the worker's forkserver, or of the API
(the ``serve`` process itself) at a seeded random moment of a bake: each time the job ends
``succeeded`` exactly once after exactly two attempts, and once ``serve`` is stopped nothing
of it is left running (a /proc scan of its process group). Short leases through
``PRT_LEASE_S``/``PRT_HEARTBEAT_S`` keep them quick; the one for the worker (lease expiry →
reaper → requeue → restarted worker → success) runs by default, the others are ``slow``.
"""

from __future__ import annotations

import itertools
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from service_harness import CORNELL, FINAL, ROOT, SLOW_SPEC, free_port
from test_bundle import TINY_SPEC
from test_service_faults import single_bundle

from jobs.config import Settings

#: Stages reported while the bake process is at work (before the bundle is written).
MID = ("gather operator", "direct texels", "direct points", "near field",
       "indirect solve")
#: Stages after which the bake may already be recorded: never kill there.
LATE = ("report", "export", "package", "done")


# -- processes, from /proc ---------------------------------------------------------------

def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, ppid, process group) of ``pid``, or None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return fields[0], int(fields[1]), int(fields[2])


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _pids() -> list[int]:
    return [int(p) for p in os.listdir("/proc") if p.isdigit()]


def live_in_group(pgid: int) -> set[int]:
    """Running (not zombie) processes of process group ``pgid``."""
    out = set()
    for pid in _pids():
        st = _stat(pid)
        if st and st[2] == pgid and st[0] != "Z":
            out.add(pid)
    return out


def children(pid: int) -> list[int]:
    out = []
    for p in _pids():
        st = _stat(p)
        if st and st[1] == pid and st[0] != "Z":
            out.append(p)
    return out


def wait_gone(pgid: int, timeout: float = 15.0) -> set[int]:
    deadline = time.monotonic() + timeout
    while (left := live_in_group(pgid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


class Serve:
    """``prtcore serve --workers 1`` in its own session (process group), on a data folder
    that survives restarts; every process of every run is accounted for at :meth:`close`."""

    def __init__(self, tmp: Path, **env: str):
        self.tmp = Path(tmp)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("PRT_")}
        self.env.update({
            "PRT_DATA_DIR": str(self.tmp / "data"),
            "PRT_LEASE_S": "2", "PRT_HEARTBEAT_S": "0.3", "PRT_REAPER_INTERVAL_S": "0.3",
            "PRT_POLL_MAX_DELAY_S": "0.1", "PRT_RESTART_BACKOFF_S": "0.2",
            "PYTHONUNBUFFERED": "1",
        })
        self.env.update(env)
        self.proc: subprocess.Popen | None = None
        self.groups: list[int] = []
        self.runs = 0

    def start(self) -> None:
        self.port = free_port()
        self.runs += 1
        log = open(self.tmp / f"serve{self.runs}.log", "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "prtcore", "serve", "--port", str(self.port),
             "--workers", "1"], cwd=ROOT, env=self.env, stdout=log,
            stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        self.groups.append(self.proc.pid)
        self.client = httpx.Client(base_url=f"http://127.0.0.1:{self.port}", timeout=30)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, "serve exited:\n" + self.log()
            try:
                if self.client.get("/readyz").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.05)
        raise AssertionError("serve did not become ready:\n" + self.log())

    def log(self) -> str:
        return "".join((self.tmp / f"serve{i}.log").read_text(errors="replace")
                       for i in range(1, self.runs + 1))

    def submit(self, spec: dict) -> str:
        with open(CORNELL, "rb") as f:
            r = self.client.post("/v1/bakes", files={
                "asset": ("cornell_box.glb", f), "spec": ("spec.json", json.dumps(spec))})
        assert r.status_code == 202, r.text
        return r.json()["id"]

    def job(self, job_id: str) -> dict:
        return self.client.get(f"/v1/bakes/{job_id}").json()

    def wait(self, job_id: str, until, timeout: float = 180.0, poll: float = 0.02) -> dict:
        deadline = time.monotonic() + timeout
        job: dict = {}
        while time.monotonic() < deadline:
            try:
                job = self.job(job_id)
                if until(job):
                    return job
            except httpx.TransportError:
                pass
            time.sleep(poll)
        raise AssertionError(f"job {job_id} never got there: {job}\n{self.log()}")

    # -- the processes of the current run -------------------------------------------------

    def worker(self) -> int:
        assert self.proc is not None
        found = [p for p in children(self.proc.pid) if " worker" in _cmdline(p)]
        assert len(found) == 1, (found, [_cmdline(p) for p in children(self.proc.pid)])
        return found[0]

    def forkserver(self) -> int:
        found = [p for p in children(self.worker()) if "forkserver" in _cmdline(p)]
        assert len(found) == 1, found
        return found[0]

    def bake(self) -> int:
        found = children(self.forkserver())
        assert len(found) == 1, found
        return found[0]

    def kill_serve(self) -> None:
        """SIGKILL the serve process alone (the API and supervisor), not its group."""
        assert self.proc is not None
        self.proc.kill()
        self.proc.wait()
        self.client.close()

    def stop(self) -> None:
        """SIGTERM serve (graceful); it must exit 0 and take every process with it."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM)
        assert self.proc.wait(timeout=60) == 0, self.log()
        self.client.close()

    def close(self) -> None:
        for g in self.groups:
            try:
                os.killpg(g, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc is not None:
            self.proc.wait()


@pytest.fixture
def make_serve(tmp_path, request):
    made: list[Serve] = []

    def make(**env: str) -> Serve:
        s = Serve(tmp_path, **env)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def _kill_and_finish(s: Serve, target: str, seed: int, spec: dict, at) -> None:
    rng = random.Random(seed)
    s.start()
    job_id = s.submit(spec)
    job = s.wait(job_id, at(rng))
    time.sleep(rng.uniform(0.0, 0.15))
    victim = {"worker": s.worker, "bake": s.bake, "forkserver": s.forkserver,
              "api": lambda: s.proc.pid}[target]()
    os.kill(victim, signal.SIGKILL)
    if target == "api":
        s.proc.wait()
        s.client.close()
        # Its workers, forkserver and bake die with it: nothing holds the queue.
        left = wait_gone(s.groups[-1])
        assert not left, f"orphans of serve: {[(p, _cmdline(p)) for p in left]}"
        s.start()
    job = s.wait(job_id, lambda j: j["status"] in FINAL)
    assert job["status"] == "succeeded", (job, s.log())
    assert job["attempts"] == 2, (job, s.log())
    log = s.log()
    assert log.count(f"job {job_id}: succeeded") == 1, log
    assert log.count(f"job {job_id}: attempt 2 of 3") == 1, log
    assert f"job {job_id}: attempt 3" not in log, log
    single_bundle(_Dirs(s), job_id)
    s.stop()
    for g in s.groups:
        left = wait_gone(g)
        assert not left, f"left running: {[(p, _cmdline(p)) for p in left]}"


class _Dirs:
    def __init__(self, s: Serve):
        self.s = s

    def job_dir(self, job_id: str) -> Path:
        return self.s.tmp / "data" / "artifacts" / job_id


def running_not_late(_rng):
    return lambda j: j["status"] == "running" and j["stage"] not in LATE


def mid_bake(rng):
    """At a seeded random stage inside the bake (or any later one of them)."""
    k = rng.randrange(len(MID))
    return lambda j: j["status"] == "running" and j["stage"] in MID[k:]


def test_kill9_of_the_only_worker_under_serve_job_still_succeeds(make_serve):
    """The worker dies mid-bake: serve restarts it, its lease expires, a reaper requeues the
    job and the new worker finishes it on attempt 2."""
    _kill_and_finish(make_serve(), "worker", 0, TINY_SPEC, running_not_late)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("target", ["worker", "bake", "forkserver", "api"])
def test_kill9_at_random_moments_job_succeeds_once(make_serve, target, seed):
    _kill_and_finish(make_serve(), target, seed, SLOW_SPEC, mid_bake)


def test_supervisor_restarts_a_dying_worker_with_backoff():
    """A worker that keeps dying is restarted after 0.1, 0.2, 0.4, 0.4 ... seconds."""
    from service.server import Supervisor

    settings = Settings(restart_backoff_s=0.1, restart_backoff_max_s=0.4,
                        restart_reset_after_s=60.0)
    starts: list[float] = []

    class Counting(Supervisor):
        POLL_S = 0.02

        def _start(self, slot):
            starts.append(time.monotonic())
            super()._start(slot)

    sup = Counting(settings, 1, env=dict(os.environ), argv=[sys.executable, "-c", "pass"])
    sup.start()
    time.sleep(2.5)
    sup.stop()
    assert not sup.is_alive()
    gaps = [b - a for a, b in itertools.pairwise(starts)]
    assert len(gaps) >= 4, gaps
    # each gap: the process's own run time (~0.05-0.3 s) + the delay, 0.1, 0.2, 0.4, 0.4...
    delays = [0.1, 0.2, 0.4, 0.4, 0.4, 0.4, 0.4]
    for gap, d in zip(gaps, delays, strict=False):
        assert gap >= d, (gaps, delays)
    assert max(gaps) < 0.4 + 2.0, gaps  # capped
