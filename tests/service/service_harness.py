"""Real processes for the service tests: uvicorn API and ``prtcore worker`` subprocesses on a
free port with a temporary data folder, each in its own process group so a test can
``kill -9`` one (bake child included) and the fixture can always clean up."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "examples" / "cornell_box.glb"
FINAL = ("succeeded", "failed", "cancelled")
#: Stages during which a bake is well under way (a kill or cancel lands mid-bake).
MID = ("lights", "gather operator", "direct texels", "direct points", "indirect solve", "fit")

#: A bake of a few seconds on the Cornell box: long enough to kill or cancel mid-bake.
SLOW_SPEC = {
    "atlas": {"resolution": 192, "padding": 2},
    "lights": {"count": 96, "holdout": 8, "families": [
        {"type": "point", "position": {"box": [[-0.8, 0.3, -0.8], [0.8, 1.9, 0.9]]},
         "intensity": {"uniform": [0.5, 3.0]}}]},
    "transport": {"gather_rays": 64, "max_bounces": 16},
    "fit": {"basis": 16},
    "output": {"dtype": "float"},
}

#: Asset-agnostic tiny spec (lights on a shell around the asset): a bake of about a second.
SHELL_SPEC = {
    "atlas": {"resolution": 32, "padding": 2},
    "measurement_points": {"count": 32, "supersample": 2},
    "lights": {"count": 16, "holdout": 4, "families": [
        {"type": "point", "position": {"shell": [1.5, 2.5]},
         "intensity": {"uniform": [0.5, 3.0]}}]},
    "transport": {"gather_rays": 16, "max_bounces": 4},
    "fit": {"basis": 4},
    "output": {"dtype": "float"},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def descendants(pid: int) -> set[int]:
    """All descendants of ``pid`` (Linux /proc)."""
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for task in tasks:
            try:
                with open(f"/proc/{p}/task/{task}/children") as f:
                    kids = {int(x) for x in f.read().split()}
            except OSError:
                kids = set()
            todo += list(kids - out)
            out |= kids
    return out


def alive(pids: set[int]) -> set[int]:
    """Those of ``pids`` that are running (not gone, not zombies)."""
    out = set()
    for p in pids:
        try:
            with open(f"/proc/{p}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] != "Z":
                    out.add(p)
        except OSError:
            pass
    return out


class Cluster:
    """An API and any number of workers sharing one configuration (``PRT_*``)."""

    def __init__(self, tmp: Path, **env: str):
        self.tmp = Path(tmp)
        self.data = self.tmp / "data"
        self.logs = self.tmp / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("PRT_")}
        self.env.update({
            "PRT_DATA_DIR": str(self.data),
            "PRT_LEASE_S": "3",
            "PRT_HEARTBEAT_S": "0.5",
            "PRT_REAPER_INTERVAL_S": "0.5",
            "PRT_POLL_MAX_DELAY_S": "0.2",
            "PYTHONUNBUFFERED": "1",
        })
        self.env.update(env)
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.procs: dict[str, subprocess.Popen] = {}
        self.client = httpx.Client(base_url=self.base, timeout=60)

    # -- processes ---------------------------------------------------------------------

    def _spawn(self, name: str, argv: list[str], env: dict[str, str] | None = None) -> None:
        log = open(self.logs / f"{name}.log", "ab")
        e = dict(self.env)
        e.update(env or {})
        self.procs[name] = subprocess.Popen(argv, cwd=ROOT, env=e, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True)
        log.close()

    def start_api(self, timeout: float = 60) -> None:
        self._spawn("api", [sys.executable, "-m", "uvicorn", "service.main:app_factory",
                            "--factory", "--host", "127.0.0.1", "--port", str(self.port),
                            "--log-level", "warning"])
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.procs["api"].poll() is not None:
                raise RuntimeError("API exited:\n" + self.log("api"))
            try:
                if self.client.get("/readyz").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        raise RuntimeError("API did not become ready:\n" + self.log("api"))

    def start_worker(self, name: str = "worker", **env: str) -> None:
        self._spawn(name, [sys.executable, "-m", "prtcore", "worker"], env)

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Signal the whole process group (the worker, its forkserver and bake)."""
        p = self.procs.pop(name)
        try:
            os.killpg(p.pid, sig)
        except ProcessLookupError:
            pass
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()

    def kill_pid_only(self, name: str) -> set[int]:
        """SIGKILL the process alone (not its group); returns its descendants of before."""
        p = self.procs.pop(name)
        kids = descendants(p.pid)
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        self.procs[f"{name}-orphans"] = p  # its group is still killed at close()
        return kids

    def close(self) -> None:
        for name in list(self.procs):
            self.kill(name)
        self.client.close()

    def log(self, name: str) -> str:
        path = self.logs / f"{name}.log"
        return path.read_text(errors="replace")[-6000:] if path.exists() else ""

    # -- API -----------------------------------------------------------------------------

    def submit(self, spec: dict, asset: Path = CORNELL, headers: dict | None = None,
               mesh: Path | None = None) -> httpx.Response:
        files = {"asset": (asset.name, asset.read_bytes(), "model/gltf-binary"),
                 "spec": ("spec.json", json.dumps(spec), "application/json")}
        if mesh is not None:  # a hair bake's head (docs/hair.md)
            files["mesh"] = (mesh.name, mesh.read_bytes(), "model/gltf-binary")
        return self.client.post("/v1/bakes", headers=headers or {}, files=files)

    def job(self, job_id: str) -> dict:
        r = self.client.get(f"/v1/bakes/{job_id}")
        r.raise_for_status()
        return r.json()

    def wait(self, job_id: str, until=lambda j: j["status"] in FINAL, timeout: float = 240,
             ) -> dict:
        """Poll until ``until(job)``; a generous liveness bound, not a timing check."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                job = self.job(job_id)
                if until(job):
                    return job
            except httpx.TransportError:
                pass  # the API is being restarted
            if time.monotonic() > deadline:
                logs = "\n".join(f"--- {n}\n{self.log(n)}" for n in
                                 sorted(p.stem for p in self.logs.glob("*.log")))
                raise AssertionError(f"job {job_id} never got there: {job}\n{logs}")
            time.sleep(0.1)

    def job_dir(self, job_id: str) -> Path:
        root = Path(self.env.get("PRT_ARTIFACTS_DIR") or self.data / "artifacts")
        return root / job_id


def mark_succeeded(db_url: str, artifacts_root: Path, job_id: str) -> Path:
    """Make a queued job ``succeeded`` with a small bundle on disk (manifest, one basis
    file, the zip), without running a bake: routes that only serve finished jobs (the
    artifact downloads and their name guard) can then be reached. Returns the bundle dir."""
    from jobs import artifacts
    from jobs.store import JobStore

    store = JobStore(db_url)
    claim = store.claim(job_id, "test", 60)
    assert claim is not None, f"job {job_id} could not be claimed"
    assert store.finish(job_id, claim.token, "succeeded")
    bundle = artifacts.bundle_dir(artifacts_root, job_id)
    bundle.mkdir(parents=True)
    (bundle / "manifest.json").write_text('{"format": "test"}', encoding="utf-8")
    (bundle / "basis_00.exr").write_bytes(b"\0" * 16)
    artifacts.write_zip(bundle, artifacts.zip_path(artifacts_root, job_id))
    store.engine.dispose()
    return bundle


def running_mid_bake(job: dict) -> bool:
    return job["status"] == "running" and job["stage"] in MID


def single_bundle(c: Cluster, job_id: str) -> None:
    """Exactly one bundle for the job, nothing half-written, the zip matching it."""
    import zipfile

    d = c.job_dir(job_id)
    assert sorted(p.name for p in d.iterdir()) == ["bundle", "bundle.zip", "input"]
    files = sorted(p.name for p in (d / "bundle").iterdir())
    assert sorted(zipfile.ZipFile(d / "bundle.zip").namelist()) == files
