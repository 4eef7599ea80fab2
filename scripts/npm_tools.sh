#!/usr/bin/env bash
# The npm packages the tests drive, pinned, installed into target/npm (never needed at run time):
# the Khronos glTF validator (scripts/gltf/validate.cjs) and playwright-core, which drives Debian's
# Chromium in the viewer's browser test (scripts/view/browser_check.cjs). Downloads no browser.
set -euo pipefail
cd "$(dirname "$0")/.."
pins=("gltf-validator@2.0.0-dev.3.10" "playwright-core@1.64.1")
missing=()
for pin in "${pins[@]}"; do
    name=${pin%@*} version=${pin##*@}
    if ! grep -qs "\"version\": \"$version\"" "target/npm/node_modules/$name/package.json"; then
        missing+=("$pin")
    fi
done
if [ ${#missing[@]} -gt 0 ]; then
    npm install --silent --no-audit --no-fund --prefix target/npm "${missing[@]}" >/dev/null
fi
