#!/usr/bin/env bash
# Silhouettes (issue 35): one synthetic subject with exact masks and the same images with masks whose edges
# are wrong by up to a few pixels (`anerf synth --mask-noise`), each trained three ways: the mask-edge band
# skipped (`train.mask_edges = "skip"`, the reference), trained with the masks' labels ("train"), and drawn
# without labels, its opacity pushed to 0 or 1 ("unlabelled"). Every variant is trained with the `fast`
# preset and evaluated on all three splits; the table adds each split's band PSNR, the PSNR outside the band
# and the predicted silhouette's area over the true one.
#
# Usage: silhouette.sh [--preset demo|realistic|realistic-exact] [--noise <px>] [--iterations N]
#                      [--out <folder>] [--seed N] [--only exact|noisy] [-- <extra train flags>]
# Defaults: the demo subject, 3 px, the preset's schedule, runs/ablation/silhouette.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
PRESET=demo
NOISE=3
ITERATIONS=""
SEED=0
ONLY=""
OUT="$ROOT/runs/ablation/silhouette"
EXTRA=()
while [ $# -gt 0 ]; do
    case "$1" in
        --preset) PRESET="$2"; shift ;;
        --noise) NOISE="$2"; shift ;;
        --iterations) ITERATIONS="$2"; shift ;;
        --seed) SEED="$2"; shift ;;
        --only) ONLY="$2"; shift ;;
        --out) OUT="$2"; shift ;;
        --) shift; EXTRA=("$@"); break ;;
        *) echo "usage: $0 [--preset P] [--noise PX] [--iterations N] [--seed N] [--only exact|noisy] [--out DIR] [-- flags]" >&2; exit 2 ;;
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
NOISY="$OUT/subject-masks-$NOISE"
[ -f "$EXACT/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" --out "$EXACT"
[ -f "$NOISY/annots.npy" ] || "$ANERF" synth --preset "$PRESET" --seed "$SEED" --mask-noise "$NOISE" --out "$NOISY"

ROWS=()
# variant <label> <subject> <mask_edges>: stage 1, stage 2 and the three splits of one variant. Evaluation
# compares against the exact subject's masks, whatever the training masks were.
variant() {
    local label="$1" subject="$2" edges="$3"
    local run="$OUT/$label"
    local schedule=()
    [ -z "$ITERATIONS" ] || schedule=(--iterations "$ITERATIONS")
    local start=$SECONDS
    "$ANERF" train --data "$subject" "${FRAMES[@]}" --preset fast --quiet --overwrite \
        --out "$run" --set "dataset.cache=$OUT/cache-$(basename "$subject")" --set "train.mask_edges=$edges" \
        "${schedule[@]}" "${EXTRA[@]}"
    echo "$label: stage 1 took $((SECONDS - start)) s"
    "$ANERF" animate "$run" --quiet
    for split in training-view novel-view novel-pose; do
        "$ANERF" eval "$run" --split "$split" --quiet --set "dataset.root=$EXACT" \
            --set "dataset.cache=$OUT/cache-$(basename "$EXACT")" >/dev/null
    done
    ROWS+=("$label=$run")
}

for edges in skip train unlabelled; do
    [ "$ONLY" = noisy ] || variant "exact-$edges" "$EXACT" "$edges"
    [ "$ONLY" = exact ] || variant "masks-$NOISE-$edges" "$NOISY" "$edges"
done
python3 "$ROOT/scripts/ablation/collect.py" --silhouette --title "Mask edges ($PRESET, masks off by ≤ $NOISE px)" \
    "${ROWS[@]}" | tee "$OUT/table.md"
