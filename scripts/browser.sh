#!/usr/bin/env bash
# The browser of the viewer tests (tests/test_viewer.py): Debian's Chromium, driven by the
# pinned Playwright (python, a dev dependency) with executable_path set to it; Playwright's
# own browser download cannot work on these machines. WebGL2 runs headless through
# SwiftShader. Idempotent: quick when Chromium is already installed. PRT_CHROMIUM names
# another binary (then nothing is installed).
set -euo pipefail
bin=${PRT_CHROMIUM:-/usr/bin/chromium}
if [ -x "$bin" ]; then
  exit 0
fi
if [ -n "${PRT_CHROMIUM:-}" ]; then
  echo "browser: PRT_CHROMIUM=$bin is not an executable" >&2
  exit 1
fi
sudo=""
if [ "$(id -u)" != 0 ]; then
  sudo="sudo"
fi
echo "browser: installing chromium (apt-get)" >&2
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null
[ -x "$bin" ] || { echo "browser: $bin missing after apt-get install chromium" >&2; exit 1; }
