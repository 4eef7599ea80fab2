# Shared by the ablations that compare a synthetic subject with a degraded copy of the same images
# (pose_refinement.sh: noisy body fits; silhouette.sh: noisy masks): arguments, the anerf binary, the
# subject's frames, the exact subject, and one variant's training and evaluation. Sourced, not run: the driver
# sets NOISE (its default noise) and USAGE_NOISE (how its --noise reads) first.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
PRESET=demo
ITERATIONS=""
SEED=0
OUT="$ROOT/runs/ablation/$(basename "$0" .sh)"
EXTRA=()
while [ $# -gt 0 ]; do
    case "$1" in
        --preset) PRESET="$2"; shift ;;
        --noise) NOISE="$2"; shift ;;
        --iterations) ITERATIONS="$2"; shift ;;
        --seed) SEED="$2"; shift ;;
        --out) OUT="$2"; shift ;;
        --) shift; EXTRA=("$@"); break ;;
        *) echo "usage: $0 [--preset P] [--noise $USAGE_NOISE] [--iterations N] [--seed N] [--out DIR] [-- flags]" >&2; exit 2 ;;
    esac
    shift
done
ANERF="${ANERF:-$ROOT/target/debug/anerf}"
[ -x "$ANERF" ] || (cd "$ROOT" && cargo build -q -p anerf --bin anerf)
mkdir -p "$OUT"

case "$PRESET" in
    demo) FRAMES=(--train-views 0,2,4,6 --train-frames 0:60 --novel-pose-frames 60:90) ;;
    tiny) FRAMES=(--train-views 0,2 --train-frames 0:6 --novel-pose-frames 6:10) ;;
    *) FRAMES=(--train-views 0,2,4,6 --train-frames 0:100 --novel-pose-frames 100:150) ;;
esac
EXACT="$OUT/subject-exact"
[ -f "$EXACT/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" --out "$EXACT"

# degraded <folder> <synth flags…>: the same subject written with `anerf synth`'s noise flags, once.
degraded() {
    local folder="$1"
    shift
    [ -f "$folder/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" "$@" --out "$folder"
}

# Flags every variant's `anerf eval` gets (a driver may set them, e.g. to compare against exact masks).
EVAL_FLAGS=()
ROWS=()
# variant <label> <subject> [train flags…]: stage 1 (the `fast` preset), stage 2 and the three splits of one
# variant into $OUT/<label>, remembered for the table.
variant() {
    local label="$1" subject="$2"
    shift 2
    local run="$OUT/$label"
    local schedule=()
    [ -z "$ITERATIONS" ] || schedule=(--iterations "$ITERATIONS")
    local start=$SECONDS
    "$ANERF" train --data "$subject" "${FRAMES[@]}" --preset fast --quiet --overwrite \
        --out "$run" --set "dataset.cache=$OUT/cache-$(basename "$subject")" \
        "${schedule[@]}" "$@" "${EXTRA[@]}"
    echo "$label: stage 1 took $((SECONDS - start)) s"
    "$ANERF" animate "$run" --quiet
    for split in training-view novel-view novel-pose; do
        "$ANERF" eval "$run" --split "$split" --quiet "${EVAL_FLAGS[@]}" >/dev/null
    done
    ROWS+=("$label=$run")
}
