#!/usr/bin/env bash
# Silhouettes (issue 35): one synthetic subject with exact masks and the same images with masks whose edges
# are wrong by up to a few pixels (`anerf synth --mask-noise`), each trained with the band around the masks'
# edges skipped (`train.mask_edges = "skip"`, the reference), trained ("train") and trained with a robust
# loss ("robust"). Every variant is trained
# with the `fast` preset and evaluated on all three splits against the exact masks; the second table gives
# each split's PSNR in the 2-pixel band around the true silhouette, outside it, and the predicted silhouette's
# area over the true one.
#
# The settings compared are EDGES (default "skip train robust"; e.g. EDGES=robust to add one to a table), on
# the masks in MASKS (default "exact noisy").
# BACKDROP=room trains on the same bodies rendered in front of a room (`anerf synth --backdrop room`), as a
# capture's images are, so that a mask's wrong labels cover a backdrop instead of black; every run is still
# evaluated against the exact subject on black.
#
# Usage: silhouette.sh [--preset demo|realistic|realistic-exact] [--noise <px>] [--iterations N]
#                      [--out <folder>] [--seed N] [-- <extra train flags>]
# Defaults: the demo subject, 3 px, the preset's schedule, runs/ablation/silhouette.
NOISE=3
USAGE_NOISE="PX"
source "$(dirname "${BASH_SOURCE[0]}")/synthetic_pair.sh"

BACKDROP="${BACKDROP:-black}"
TAG=""
TRAIN_EXACT="$EXACT"
if [ "$BACKDROP" != black ]; then
    TAG="-$BACKDROP"
    TRAIN_EXACT="$OUT/subject-exact$TAG"
    degraded "$TRAIN_EXACT" --backdrop "$BACKDROP"
fi
MASKS="${MASKS:-exact noisy}"
NOISY="$OUT/subject-masks-$NOISE$TAG"
[[ " $MASKS " != *" noisy "* ]] || degraded "$NOISY" --mask-noise "$NOISE" --backdrop "$BACKDROP"
# Every run is evaluated against the exact subject's masks and images on black (the bodies are the same).
EVAL_FLAGS=(--set "dataset.root=$EXACT" --set "dataset.cache=$OUT/cache-$(basename "$EXACT")")
for edges in ${EDGES:-skip train robust}; do
    [[ " $MASKS " != *" exact "* ]] || variant "exact$TAG-$edges" "$TRAIN_EXACT" --set "train.mask_edges=$edges"
    [[ " $MASKS " != *" noisy "* ]] || variant "masks-$NOISE$TAG-$edges" "$NOISY" --set "train.mask_edges=$edges"
done
# The title names the noisy masks' size only where a noisy subject was trained.
TITLE="Mask edges ($PRESET, $BACKDROP"
[[ " $MASKS " != *" noisy "* ]] || TITLE+=", noisy masks off by ≤ $NOISE px"
python3 "$ROOT/scripts/ablation/collect.py" --silhouette --title "$TITLE)" "${ROWS[@]}" | tee "$OUT/table.md"
