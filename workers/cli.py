"""``prtcore worker``, registered with the ``prtcore`` command through the entry-point group
``prtcore.commands`` (pyproject.toml), so the library never imports the workers. Kept
light: argparse only; the worker is imported when the command runs."""

from __future__ import annotations

import argparse
import os


def _cmd_worker(args: argparse.Namespace) -> int:
    """One queue consumer running bakes (configuration from PRT_* variables)."""
    if args.concurrency is not None:
        os.environ["PRT_CONCURRENCY"] = str(args.concurrency)
    from .main import run_worker

    run_worker()
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    sp = subparsers.add_parser("worker",
                               help="bake worker: consume the job queue (PRT_* settings)")
    sp.add_argument("--concurrency", type=int, default=None,
                    help="bakes at once (default PRT_CONCURRENCY or 1)")
    sp.set_defaults(func=_cmd_worker)
