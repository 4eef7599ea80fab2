#!/usr/bin/env bash
# The viewer's browser test (run by .ci/run): serves a run with `anerf view` and checks the page in
# headless Chromium (scripts/view/browser_check.cjs): the avatar drawn in the 3D view, the baked Gaussians
# drawn from an orbit and from a dataset camera, the curves and an evaluation image loaded, the view filter, no console error. Without --run it trains, animates,
# evaluates and exports a tiny synthetic run first (about 15 s in the dev profile).
#
# usage: scripts/view/browser_test.sh [--run DIR] [--screenshot FILE]
#   --run DIR         an evaluated, exported (glb and ply) run whose baked avatar is evaluated on the
#                     training views (the README's picture: the demo's run)
#   --screenshot FILE where the screenshot goes (default: target/view/screenshot.png)
# ANERF names the binary (default: target/debug/anerf, built when missing); CHROMIUM the browser
# (default /usr/bin/chromium: Debian's `chromium` package).
set -euo pipefail
cd "$(dirname "$0")/../.."

run="" screenshot="target/view/screenshot.png"
while [ $# -gt 0 ]; do
    case "$1" in
        --run) run="$2"; shift 2 ;;
        --screenshot) screenshot="$2"; shift 2 ;;
        *) echo "unknown argument $1 (usage: $0 [--run DIR] [--screenshot FILE])" >&2; exit 2 ;;
    esac
done

chromium=${CHROMIUM:-/usr/bin/chromium}
if [ ! -x "$chromium" ]; then
    echo "error: no Chromium at $chromium: install Debian's package (apt-get install chromium) or set CHROMIUM" >&2
    exit 1
fi
bash scripts/npm_tools.sh
anerf=${ANERF:-target/debug/anerf}
if [ ! -x "$anerf" ]; then
    cargo build --quiet -p anerf --bin anerf
fi

work=$(mktemp -d)
server=""
cleanup() {
    [ -n "$server" ] && kill "$server" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT

# Runs one command quietly; on failure shows what it printed.
step() {
    "$@" >"$work/step.log" 2>&1 || { cat "$work/step.log" >&2; echo "error: failed: $*" >&2; exit 1; }
}

start=$(date +%s)
if [ -z "$run" ]; then
    run="$work/run"
    step "$anerf" synth --preset tiny --out "$work/subject"
    step "$anerf" train --data "$work/subject" --preset tiny --out "$run" --set dataset.cache="$work/cache" --quiet
    step "$anerf" animate "$run" --quiet
    step "$anerf" eval "$run" --quiet
    # The tiny run's density is low after 200 steps: a low iso level still finds its surface.
    step "$anerf" export "$run" --level 1 --voxel 0.02
    # The baked avatar for the Gaussian view: a short fit of a few thousand Gaussians.
    step "$anerf" bake "$run" --level 1 --voxel 0.02 --budget 4000 --iterations 60 --quiet
    step "$anerf" export "$run" --format ply
    step "$anerf" eval "$run" --baked --split training-view --quiet
fi

"$anerf" view "$run" --port 0 >"$work/view.log" 2>&1 &
server=$!
url=""
for _ in $(seq 50); do
    url=$(grep -o 'http://127\.0\.0\.1:[0-9]*/' "$work/view.log" || true)
    [ -n "$url" ] && break
    kill -0 "$server" 2>/dev/null || { cat "$work/view.log" >&2; exit 1; }
    sleep 0.1
done
[ -n "$url" ] || { echo "error: anerf view printed no address" >&2; cat "$work/view.log" >&2; exit 1; }

mkdir -p "$(dirname "$screenshot")"
CHROMIUM="$chromium" NODE_PATH=target/npm/node_modules node scripts/view/browser_check.cjs "$url" "$screenshot"
echo "browser test passed in $(( $(date +%s) - start )) s; screenshot in $screenshot"
