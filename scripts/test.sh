#!/usr/bin/env bash
# The test command of the README: writes the numpy/scipy fixtures, then runs every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! python3 -c "import numpy, scipy, skimage, PIL, plyfile, cv2" 2>/dev/null; then
    python3 -m pip install --quiet -r scripts/fixtures/requirements.txt
fi
python3 scripts/fixtures/generate.py --out target/fixtures
# The pinned npm tools the tests drive (the glTF validator; playwright-core for the browser test).
bash scripts/npm_tools.sh
cargo test --workspace
