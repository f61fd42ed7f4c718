"""``openapi.yaml`` from the app: ``python -m service.openapi [--check]``.

``--check`` exits 1 when the committed file differs (the drift test runs the same
comparison)."""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PATH = ROOT / "openapi.yaml"
HEADER = "# Generated from the FastAPI app by `python -m service.openapi`; do not edit.\n"


def render() -> str:
    from jobs.config import Settings

    from .main import create_app

    spec = create_app(Settings()).openapi()
    return HEADER + yaml.safe_dump(spec, sort_keys=False, allow_unicode=True, width=100)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    text = render()
    if "--check" in argv:
        if PATH.read_text(encoding="utf-8") != text:
            print(f"{PATH} is out of date: run python -m service.openapi", file=sys.stderr)
            return 1
        return 0
    PATH.write_text(text, encoding="utf-8")
    print(f"wrote {PATH}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
