"""``prtcore serve``, registered with the ``prtcore`` command through the entry-point group
``prtcore.commands`` (pyproject.toml), so the library never imports the service. Kept
light: argparse only; the server is imported when the command runs."""

from __future__ import annotations

import argparse


def _cmd_serve(args: argparse.Namespace) -> int:
    """API + supervised workers on this machine."""
    from .server import serve

    return serve(host=args.host, port=args.port, workers=args.workers,
                 api_workers=args.api_workers)


def register(subparsers: argparse._SubParsersAction) -> None:
    sp = subparsers.add_parser("serve",
                               help="bake service: HTTP API and workers (PRT_* settings)")
    sp.add_argument("--host", default="127.0.0.1")
    sp.add_argument("--port", type=int, default=8000)
    sp.add_argument("--workers", type=int, default=1, help="worker processes to start")
    sp.add_argument("--api-workers", type=int, default=1, help="uvicorn worker processes")
    sp.set_defaults(func=_cmd_serve)
