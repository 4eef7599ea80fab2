#!/usr/bin/env bash
# Pose refinement (issue 35): one synthetic subject with exact body fits, the same images with noisy fits
# (`anerf synth --pose-noise`), and the noisy fits refined in stage 1 (`model.pose_refinement.enabled`);
# every variant trained with the `fast` preset and evaluated on all three splits, and how far each run's fits
# lie from the true poses (scripts/ablation/pose_error.py).
#
# Usage: pose_refinement.sh [--preset demo|realistic|realistic-exact] [--noise <deg>[,<cm>]]
#                           [--iterations N] [--out <folder>] [--seed N] [-- <extra train flags>]
# Defaults: the demo subject, 1.5° (1 cm), the preset's schedule, runs/ablation/pose_refinement.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
PRESET=demo
NOISE=1.5
ITERATIONS=""
SEED=0
OUT="$ROOT/runs/ablation/pose_refinement"
EXTRA=()
while [ $# -gt 0 ]; do
    case "$1" in
        --preset) PRESET="$2"; shift ;;
        --noise) NOISE="$2"; shift ;;
        --iterations) ITERATIONS="$2"; shift ;;
        --seed) SEED="$2"; shift ;;
        --out) OUT="$2"; shift ;;
        --) shift; EXTRA=("$@"); break ;;
        *) echo "usage: $0 [--preset P] [--noise DEG[,CM]] [--iterations N] [--seed N] [--out DIR] [-- flags]" >&2; exit 2 ;;
    esac
    shift
done
ANERF="${ANERF:-$ROOT/target/debug/anerf}"
[ -x "$ANERF" ] || (cd "$ROOT" && cargo build -q -p anerf-train --bin anerf)
mkdir -p "$OUT"

case "$PRESET" in
    demo) FRAMES=(--train-views 0,2,4,6 --train-frames 0:60 --novel-pose-frames 60:90) ;;
    tiny) FRAMES=(--train-views 0,2 --train-frames 0:6 --novel-pose-frames 6:10) ;;
    *) FRAMES=(--train-views 0,2,4,6 --train-frames 0:100 --novel-pose-frames 100:150) ;;
esac
EXACT="$OUT/subject-exact"
NOISY="$OUT/subject-noisy"
[ -f "$EXACT/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" --out "$EXACT"
[ -f "$NOISY/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" --pose-noise "$NOISE" --out "$NOISY"

ROWS=()
# variant <label> <subject> [--set …]: stage 1, stage 2 and the three splits of one variant.
variant() {
    local label="$1" subject="$2"
    shift 2
    local run="$OUT/$label"
    local schedule=()
    [ -z "$ITERATIONS" ] || schedule=(--iterations "$ITERATIONS")
    local start=$SECONDS
    "$ANERF" train --data "$subject" "${FRAMES[@]}" --preset fast --quiet --overwrite \
        --out "$run" --set "dataset.cache=$OUT/cache-$(basename "$subject")" --set train.mask_edges=train \
        "${schedule[@]}" "$@" "${EXTRA[@]}"
    echo "$label: stage 1 took $((SECONDS - start)) s"
    "$ANERF" animate "$run" --quiet
    for split in training-view novel-view novel-pose; do
        "$ANERF" eval "$run" --split "$split" --quiet >/dev/null
    done
    if [ -f "$run/refined_poses.json" ]; then
        python3 "$ROOT/scripts/ablation/pose_error.py" "$NOISY" "$run" | sed "s/^/$label: /"
    fi
    ROWS+=("$label=$run")
}

variant exact "$EXACT"
variant noisy "$NOISY"
variant noisy-refined "$NOISY" --set model.pose_refinement.enabled=true
python3 "$ROOT/scripts/ablation/collect.py" --title "Body fits ($PRESET, noise $NOISE)" "${ROWS[@]}" \
    | tee "$OUT/table.md"
