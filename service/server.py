"""``prtcore serve``: the API (uvicorn) and worker processes on one machine.

Embedded defaults need no external server (SQLite job store and queue, artifacts under
``PRT_DATA_DIR``). The workers are separate processes — bakes never run in the API process —
started as ``python -m prtcore worker`` with the same environment, and stopped with it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from .config import get_settings


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1,
          api_workers: int = 1) -> int:
    import uvicorn

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("PRT_DATA_DIR", str(settings.data_dir.resolve()))
    # uvicorn shuts down gracefully on SIGTERM, restores this handler and re-raises the
    # signal: turn it into a normal exit so the workers below are stopped too.
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    procs = [subprocess.Popen([sys.executable, "-m", "prtcore", "worker"], env=env)
             for _ in range(max(0, workers))]
    try:
        uvicorn.run("service.main:app_factory", factory=True, host=host, port=port,
                    workers=api_workers, log_level="info", access_log=False)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    return 0


def _exit_on_sigterm(_sig: int, _frame: object) -> None:
    raise SystemExit(0)
