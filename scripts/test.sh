#!/usr/bin/env bash
# Quick start, command 2: set up .venv and run the whole test suite (slow tests included).
# In the inner loop, `.venv/bin/pytest` alone skips the tests marked slow.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
bash scripts/services.sh  # PostgreSQL + Redis for the scale-out service tests
bash scripts/browser.sh   # Chromium for the viewer tests (tests/test_viewer.py)
.venv/bin/ruff check .
exec .venv/bin/python -m pytest -m "" -q "$@"
