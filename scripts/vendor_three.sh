#!/usr/bin/env bash
# Refresh the vendored three.js of the web viewer (prtcore/viewer/static/three/) from the
# npm package, and rewrite its checksum list (tests/test_viewer_vendor.py checks it).
# Usage: bash scripts/vendor_three.sh [VERSION]   (default: the pinned one below)
# Needs npm (the registry) and network; nothing else in the project does.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSION=${1:-0.187.0}
DEST=prtcore/viewer/static/three
# The files the viewer imports (and what they import), plus the licence. EXRLoader.js keeps
# its BSD notices (TinyEXR, OpenEXR) in its header; it is copied unchanged.
FILES=(
  LICENSE
  build/three.module.js
  build/three.core.js
  examples/jsm/controls/OrbitControls.js
  examples/jsm/controls/TransformControls.js
  examples/jsm/loaders/GLTFLoader.js
  examples/jsm/loaders/EXRLoader.js
  examples/jsm/libs/fflate.module.js
  examples/jsm/utils/BufferGeometryUtils.js
  examples/jsm/utils/SkeletonUtils.js
)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm pack --silent "three@$VERSION" > /dev/null && tar xzf "three-$VERSION.tgz")
rm -rf "$DEST"
for f in "${FILES[@]}"; do
  mkdir -p "$DEST/$(dirname "$f")"
  cp "$tmp/package/$f" "$DEST/$f"
done
echo "$VERSION" > "$DEST/VERSION"
(cd "$DEST" && find . -type f ! -name SHA256SUMS | sed 's|^\./||' | LC_ALL=C sort \
  | xargs sha256sum > SHA256SUMS)
echo "vendored three@$VERSION into $DEST ($(wc -l < "$DEST/SHA256SUMS") files)"
