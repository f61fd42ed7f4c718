#!/usr/bin/env bash
# Quick start, command 1: set up .venv and bake the bundled Cornell box example.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=${1:-out/cornell_box}
.venv/bin/prtcore bake examples/cornell_box.glb --spec examples/cornell_box.spec.json \
  --out "$out" --force
