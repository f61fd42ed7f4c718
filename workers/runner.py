"""One attempt of one job, as run by a queue consumer thread.

claim (conditional update: queued → running, attempts + 1, lease) → check the artifact
location → bake in a child process while this thread renews the lease every
``heartbeat_s``, enforces the time limit and watches for a lost lease → record the outcome:
succeeded; cancelled; failed for bad input, an unwritable artifact location or the time
limit; otherwise back to queued (and re-sent) until ``max_attempts`` is spent.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import threading
import time
from functools import lru_cache

from jobs import artifacts
from jobs.config import Settings, get_settings
from jobs.queue import enqueue
from jobs.store import JobStore

log = logging.getLogger("prtcore.worker")

_PRELOAD = ["workers.bake_child"]


@lru_cache(maxsize=1)
def get_store() -> JobStore:
    return JobStore(get_settings().db_url)


@lru_cache(maxsize=1)
def _context() -> mp.context.BaseContext:
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)
    return ctx


def start_forkserver() -> None:
    """Start the forkserver (prtcore preloaded) now rather than at the first bake. If it
    dies later, multiprocessing starts a new one at the next bake."""
    from multiprocessing import forkserver

    _context()
    forkserver.ensure_running()


class Heartbeat(threading.Thread):
    """Renews the lease every ``heartbeat_s`` from claim to outcome, whatever the attempt is
    doing (starting the bake process included); a failed renewal (database blip) is retried
    at the next beat, a renewal that finds the lease gone sets :attr:`lost`."""

    def __init__(self, store: JobStore, job_id: str, token: str, settings: Settings):
        super().__init__(name=f"heartbeat-{job_id}", daemon=True)
        self.store, self.job_id, self.token, self.settings = store, job_id, token, settings
        self.done = threading.Event()
        self.lost = threading.Event()

    def run(self) -> None:
        while not self.done.wait(self.settings.heartbeat_s):
            try:
                ours, _cancel = self.store.heartbeat(self.job_id, self.token,
                                                     self.settings.lease_s)
            except Exception as e:  # transient database error: try again at the next beat
                log.warning("job %s: heartbeat failed: %s", self.job_id, e)
                continue
            if not ours:
                self.lost.set()
                return


def worker_name(settings: Settings) -> str:
    return settings.worker_name or f"{socket.gethostname()}:{os.getpid()}"


def run_job(job_id: str, settings: Settings | None = None, store: JobStore | None = None
            ) -> str | None:
    """Run one attempt of ``job_id`` if it can be claimed. Returns the job's new status
    (``None`` when the message was stale: job not queued, or claimed elsewhere)."""
    settings = settings or get_settings()
    store = store or get_store()
    claim = store.claim(job_id, worker_name(settings), settings.lease_s)
    if claim is None:
        log.info("job %s: not claimable (stale message)", job_id)
        return None
    job, token = claim.job, claim.token
    log.info("job %s: attempt %d of %d", job_id, job.attempts, job.max_attempts)
    beat = Heartbeat(store, job_id, token, settings)
    beat.start()
    try:
        outcome = _attempt(settings, store, job, token, beat)
    finally:
        beat.done.set()
    if outcome == "queued":
        enqueue(job_id)
    log.info("job %s: %s", job_id, outcome)
    return outcome


def _attempt(settings: Settings, store: JobStore, job, token: str, beat: Heartbeat
             ) -> str | None:
    job_id = job.id
    root = settings.artifacts
    try:
        artifacts.check_writable(root, job_id)
    except OSError as e:
        where = artifacts.job_dir(root, job_id)
        store.finish(job_id, token, "failed", error_code="artifacts_unwritable",
                     error_message=f"artifact location not writable: {where}: "
                                   f"{e.strerror or e}")
        return "failed"
    if not (artifacts.input_dir(root, job_id) / job.asset_name).is_file():
        store.finish(job_id, token, "failed", error_code="input_missing",
                     error_message=f"uploaded asset missing from the artifact location: "
                                   f"{artifacts.input_dir(root, job_id) / job.asset_name}")
        return "failed"
    # An earlier attempt may have finished the bundle and died before recording it: the
    # bake is deterministic, so a complete bundle + zip is this job's result.
    if (artifacts.bundle_dir(root, job_id) / "manifest.json").is_file() and \
            artifacts.zip_path(root, job_id).is_file():
        store.finish(job_id, token, "succeeded", timings=job.timings)
        return "succeeded"

    from .bake_child import child_main

    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    # The child holds the read end of a pipe whose only write end stays here: if this
    # process dies (kill -9), the child reads EOF and kills itself.
    life_r, life_w = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=child_main, name=f"bake-{job_id}",
                       args=(settings, job_id, token, job.asset_name, job.spec_json, send,
                             life_r))
    proc.start()
    send.close()
    life_r.close()
    t0 = time.monotonic()
    result: dict | None = None
    outcome: str | None = None
    try:
        while True:
            if recv.poll(0.2):
                try:
                    result = recv.recv()
                except EOFError:  # the bake process died without a word
                    result = None
                break
            if not proc.is_alive() and not recv.poll(0):
                break
            if beat.lost.is_set():
                log.warning("job %s: lease lost, stopping the bake", job_id)
                proc.kill()
                return None
            if time.monotonic() - t0 > settings.job_time_limit_s:
                proc.kill()
                proc.join()
                store.finish(job_id, token, "failed", error_code="time_limit",
                             error_message=f"bake exceeded the time limit of "
                                           f"{settings.job_time_limit_s:g} s")
                return "failed"
    finally:
        proc.join(timeout=30)
        if proc.is_alive():
            proc.kill()
            proc.join()
        recv.close()
        life_w.close()

    if result is None:
        code = proc.exitcode
        why = (f"killed by signal {-code}" if code is not None and code < 0
               else f"exit status {code}")
        outcome = store.retry_or_fail(job_id, token, "bake_crashed",
                                      f"the bake process died ({why}) on attempt "
                                      f"{job.attempts} of {job.max_attempts}")
    else:
        status = result["status"]
        timings = result.get("timings") or {}
        if status == "succeeded":
            outcome = "succeeded" if store.finish(job_id, token, "succeeded",
                                                  timings=timings) else None
        elif status == "cancelled":
            outcome = "cancelled" if store.finish(job_id, token, "cancelled",
                                                  error_code="cancelled",
                                                  error_message="cancelled by request",
                                                  timings=timings) else None
        elif status == "lost":
            outcome = None
        elif not result.get("retry"):
            outcome = "failed" if store.finish(job_id, token, "failed",
                                               error_code=result["code"],
                                               error_message=result["message"],
                                               timings=timings) else None
        else:
            outcome = store.retry_or_fail(job_id, token, result["code"], result["message"])
    return outcome
