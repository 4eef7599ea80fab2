#!/usr/bin/env bash
# The test command of the README: writes the numpy/scipy fixtures, then runs every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! python3 -c "import numpy, scipy, skimage, PIL, plyfile, cv2" 2>/dev/null; then
    python3 -m pip install --quiet -r scripts/fixtures/requirements.txt
fi
python3 scripts/fixtures/generate.py --out target/fixtures
# The Khronos glTF validator the export tests run (scripts/gltf/validate.cjs), pinned.
GLTF_VALIDATOR=2.0.0-dev.3.10
if ! grep -qs "\"version\": \"$GLTF_VALIDATOR\"" target/npm/node_modules/gltf-validator/package.json; then
    npm install --silent --no-audit --no-fund --prefix target/npm "gltf-validator@$GLTF_VALIDATOR" >/dev/null
fi
cargo test --workspace
