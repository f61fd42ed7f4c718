"""Service load benchmark: status-call latency and throughput while bakes run.

Starts ``prtcore serve`` (embedded mode: SQLite store and queue, one worker process baking
``--concurrency`` jobs at once, by default 2 = both cores of the dev machine) in a temporary
data folder, submits ``--jobs`` Cornell-box bakes, and runs ``--clients`` concurrent
clients polling ``GET /v1/bakes/{id}`` until every bake has finished.

    .venv/bin/python benchmarks/service_load.py [--clients 8] [--jobs 8] [--resolution 192]

Prints status-call p50/p99 latency and jobs/minute; writes
benchmarks/results/service_load.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
FINAL = ("succeeded", "failed", "cancelled")


def bake_spec(resolution: int, seed: int) -> dict:
    return {
        "atlas": {"resolution": resolution, "padding": 2},
        "lights": {"count": 96, "holdout": 8, "seed": seed, "families": [
            {"type": "point", "position": {"box": [[-0.8, 0.3, -0.8], [0.8, 1.9, 0.9]]},
             "intensity": {"uniform": [0.5, 3.0]}}]},
        "transport": {"gather_rays": 64, "max_bounces": 16},
        "fit": {"basis": 16},
        "output": {"dtype": "float"},
    }


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=8, help="concurrent polling clients")
    ap.add_argument("--jobs", type=int, default=8, help="bakes to run")
    ap.add_argument("--concurrency", type=int, default=2, help="bakes at once")
    ap.add_argument("--resolution", type=int, default=192, help="atlas size of each bake")
    ap.add_argument("--interval", type=float, default=0.02,
                    help="pause between one client's calls, seconds")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "service_load.json"))
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="prt-load-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PRT_")}
    env.update(PRT_DATA_DIR=str(tmp / "data"), PRT_CONCURRENCY=str(args.concurrency),
               PRT_POLL_MAX_DELAY_S="0.2")
    log = open(tmp / "serve.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "prtcore", "serve", "--port", str(port),
                             "--workers", "1"], cwd=ROOT, env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        with httpx.Client(base_url=base, timeout=60) as c:
            deadline = time.monotonic() + 60
            while True:
                try:
                    if c.get("/readyz").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit("service did not start; see " + str(tmp / "serve.log"))
                time.sleep(0.1)
            time.sleep(2.0)  # let the worker start its forkserver before timing
            t0 = time.perf_counter()
            ids = []
            for k in range(args.jobs):
                r = c.post("/v1/bakes", files={
                    "asset": (CORNELL.name, CORNELL.read_bytes(), "model/gltf-binary"),
                    "spec": ("spec.json", json.dumps(bake_spec(args.resolution, k)))})
                r.raise_for_status()
                ids.append(r.json()["id"])

        stop = threading.Event()
        samples: list[list[float]] = [[] for _ in range(args.clients)]
        errors = [0] * args.clients

        def client(i: int) -> None:
            rng = np.random.default_rng(i)
            with httpx.Client(base_url=base, timeout=30) as cl:
                while not stop.is_set():
                    job_id = ids[int(rng.integers(len(ids)))]
                    t = time.perf_counter()
                    r = cl.get(f"/v1/bakes/{job_id}")
                    samples[i].append(time.perf_counter() - t)
                    if r.status_code != 200:
                        errors[i] += 1
                    time.sleep(args.interval)

        threads = [threading.Thread(target=client, args=(i,)) for i in range(args.clients)]
        for t in threads:
            t.start()
        with httpx.Client(base_url=base, timeout=60) as c:
            while True:
                jobs = [c.get(f"/v1/bakes/{i}").json() for i in ids]
                if all(j["status"] in FINAL for j in jobs):
                    break
                time.sleep(0.5)
        elapsed = time.perf_counter() - t0
        stop.set()
        for t in threads:
            t.join()
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()

    lat = np.array([x for s in samples for x in s]) * 1000.0
    ok = sum(j["status"] == "succeeded" for j in jobs)
    result = {
        "clients": args.clients, "jobs": args.jobs, "concurrency": args.concurrency,
        "resolution": args.resolution, "interval_s": args.interval,
        "status_calls": int(lat.size), "status_errors": int(sum(errors)),
        "status_ms": {"p50": float(np.percentile(lat, 50)),
                      "p90": float(np.percentile(lat, 90)),
                      "p99": float(np.percentile(lat, 99)), "max": float(lat.max())},
        "succeeded": ok, "elapsed_s": elapsed, "jobs_per_minute": ok / elapsed * 60.0,
        "bake_seconds": [round(sum(j["timings"].values()), 3) for j in jobs],
        "machine": platform.uname()._asdict(), "cpus": os.cpu_count(),
    }
    print(f"status calls   {lat.size} from {args.clients} clients, {sum(errors)} errors")
    print(f"status latency p50 {result['status_ms']['p50']:.1f} ms   "
          f"p99 {result['status_ms']['p99']:.1f} ms   max {result['status_ms']['max']:.1f} ms")
    print(f"throughput     {ok}/{args.jobs} bakes succeeded in {elapsed:.1f} s = "
          f"{result['jobs_per_minute']:.1f} jobs/minute ({args.concurrency} at once)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
