"""The bake process: one attempt of one job, started by :mod:`workers.runner`.

A separate process (from a forkserver preloaded with prtcore) so that the worker that
holds the lease keeps heartbeating whatever the bake does, can enforce the job's time
limit by killing it, and survives a crash of the bake itself. The bake publishes stage and
progress through the job store and stops at the next stage boundary when the job is
cancelled or its lease was lost.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from jobs import artifacts
from jobs.config import Settings
from jobs.lifeline import set_parent_death_signal
from jobs.store import JobStore

# Preloaded in the forkserver: the library (its public names) and what a bake imports
# lazily — importing ``bake`` loads the pipeline.
from prtcore import AssetError, PrtError, SpecError, bake


class Stop(Exception):
    """Raised from the progress callback to stop at a stage boundary."""

    def __init__(self, status: str):
        super().__init__(status)
        self.status = status


def error_code(e: BaseException) -> tuple[str, bool]:
    """(code, worth retrying) for an exception raised by a bake."""
    if isinstance(e, AssetError):
        return "invalid_asset", False
    if isinstance(e, SpecError):
        return "invalid_spec", False
    if isinstance(e, PrtError):
        return "bake_error", False
    if isinstance(e, MemoryError):
        return "out_of_memory", True
    if isinstance(e, OSError):
        return "io_error", True
    return "internal_error", True


def _watch_lifeline(lifeline: Connection) -> None:
    """Block on the worker's lifeline; when the worker is gone (EOF), die at once — a bake
    whose lease holder is dead must not go on writing (its job runs again elsewhere)."""
    try:
        lifeline.recv()
    except (EOFError, OSError):
        pass
    os.kill(os.getpid(), signal.SIGKILL)


def child_main(settings: Settings, job_id: str, token: str, asset_name: str,
               spec_json: str, conn: Connection, lifeline: Connection) -> None:
    """Run the bake; send one result dict through ``conn`` (unless killed)."""
    import threading

    # Our parent is the forkserver: if it dies, so do we (no orphaned bakes); if the
    # worker dies, the lifeline below takes us down.
    set_parent_death_signal(signal.SIGKILL)
    threading.Thread(target=_watch_lifeline, args=(lifeline,), daemon=True,
                     name="lifeline").start()
    with contextlib.suppress(OSError):
        os.nice(settings.bake_nice)
    result: dict[str, Any]
    timings: dict[str, float] = {}
    try:
        result = _bake(settings, job_id, token, asset_name, spec_json, timings)
    except Stop as s:
        result = {"status": s.status}
    except BaseException as e:  # report everything; the parent decides about retries
        code, retry = error_code(e)
        msg = str(e) if isinstance(e, PrtError) else f"{type(e).__name__}: {e}"
        result = {"status": "error", "code": code, "message": msg[:2000], "retry": retry}
    result["timings"] = timings
    conn.send(result)
    conn.close()


def _bake(settings: Settings, job_id: str, token: str, asset_name: str, spec_json: str,
          timings: dict[str, float]) -> dict[str, Any]:
    from prtcore import STAGES, IntakeLimits, parse_spec

    store = JobStore(settings.db_url, create=False)
    root = settings.artifacts
    started: dict[str, float] = {}
    done = [0.0]

    def callback(stage: str, fraction: float) -> None:
        now = time.perf_counter()
        if fraction <= 0.0:
            started[stage] = now
            if settings.fault_crash_stage and stage == settings.fault_crash_stage:
                os.kill(os.getpid(), signal.SIGKILL)  # fault injection (tests only)
            if stage in STAGES:  # progress: the share of the bake's stages started
                done[0] = max(done[0], STAGES.index(stage) / len(STAGES))
            ours, cancel = store.progress(job_id, token, stage, done[0], timings)
            if not ours:
                raise Stop("lost")
            if cancel:
                raise Stop("cancelled")
        else:
            timings[stage] = round(timings.get(stage, 0.0) + now - started.get(stage, now), 4)

    spec = parse_spec(json.loads(spec_json))
    artifacts.clean_partials(root, job_id)
    asset = artifacts.input_dir(root, job_id) / asset_name
    out = artifacts.bundle_dir(root, job_id)
    job = store.get(job_id)
    # a hair bake's head, uploaded as the 'mesh' part (service/uploads.py)
    mesh = next((p for p in (artifacts.input_dir(root, job_id) / f"mesh{x}"
                             for x in (".glb", ".gltf")) if p.is_file()), None)
    bake(asset, spec, out, quiet=True, force=True, limits=IntakeLimits.from_env(),
         callback=callback, source_name=job.original_name if job else None, mesh=mesh)
    ours, _cancel = store.progress(job_id, token, "package", done[0], timings)
    if not ours:
        raise Stop("lost")
    artifacts.write_zip(out, artifacts.zip_path(root, job_id))
    store.engine.dispose()
    return {"status": "succeeded", "bundle": str(Path(out))}
