#!/usr/bin/env bash
# Times the README's recipe for a folder on the realistic subject, command by command, from an empty cache:
# train (preparation included), animate, and the three evaluation splits. Prints each command's seconds and
# the total; the figures of docs/PERFORMANCE.md, "The recipe with a fresh cache".
#
#   scripts/bench/recipe.sh [work folder (default: target/bench/recipe) [train flags…]]
#
# Needs the subject (`anerf synth --preset realistic --out data/synthetic/realistic`) and a release build
# (`cargo build --release -p anerf`); ANERF=<binary> times another build. DATA=<subject> times another
# subject: a subject whose fits are not exact (`anerf synth --preset realistic-exact --pose-noise 2.5`, as a
# real capture's) trains with pose refinement, as `train --data` does for a capture. Everything it writes
# stays in the work folder, which must not exist yet (a run folder is never overwritten). Flags after the
# folder go to `train` (`--set train.detail_fraction=0.25`), for a variant of the recipe.
set -euo pipefail
cd "$(dirname "$0")/../.."
anerf="${ANERF:-target/release/anerf}"
data="${DATA:-data/synthetic/realistic}"
work="${1:-target/bench/recipe}"
shift $(($# > 0 ? 1 : 0))
[[ -x "$anerf" ]] || { echo "no $anerf: cargo build --release -p anerf" >&2; exit 1; }
[[ -d "$data" ]] || { echo "no $data: anerf synth --preset realistic --out $data" >&2; exit 1; }
[[ -e "$work" ]] && { echo "$work exists: name a new folder" >&2; exit 1; }
anerf="$(realpath "$anerf")"
data="$(realpath "$data")"
mkdir -p "$work"
cd "$work"

total=0
timed() {
    local name="$1"
    shift
    local start end
    start=$(date +%s.%N)
    "$anerf" "$@" --quiet > "$name.log" 2>&1 || { echo "$name failed: see $work/$name.log" >&2; exit 1; }
    end=$(date +%s.%N)
    local secs
    secs=$(python3 -c "print(f'{$end - $start:.1f}')")
    total=$(python3 -c "print(f'{$total + $secs:.1f}')")
    echo "$name: $secs s"
}
# The cache goes into the work folder (train --data writes it to the working directory), so it starts empty.
timed train train --data "$data" --train-views 0,2,4,6 --train-frames 0:100 --novel-pose-frames 100:150 \
    --preset fast --out run "$@"
timed animate animate run
timed eval-novel-view eval run --split novel-view
timed eval-novel-pose eval run --split novel-pose
timed eval-training-view eval run --split training-view
echo "total: $total s"
grep -h "stage 1 finished" train.log || true
