#!/usr/bin/env bash
# Pose refinement (issue 35): one synthetic subject with exact body fits, the same images with noisy fits
# (`anerf synth --pose-noise`), and the noisy fits refined in stage 1 (`model.pose_refinement.enabled`);
# every variant trained with the `fast` preset and evaluated on all three splits, and how far each run's fits
# lie from the true poses (scripts/ablation/pose_error.py).
#
# Usage: pose_refinement.sh [--preset demo|realistic|realistic-exact] [--noise <deg>[,<cm>]]
#                           [--iterations N] [--out <folder>] [--seed N] [-- <extra train flags>]
# Defaults: the demo subject, 1.5° (1 cm), the preset's schedule, runs/ablation/pose_refinement.
NOISE=1.5
USAGE_NOISE="DEG[,CM]"
source "$(dirname "${BASH_SOURCE[0]}")/synthetic_pair.sh"

NOISY="$OUT/subject-noisy"
degraded "$NOISY" --pose-noise "$NOISE"
# The synthetic masks are exact: the band around their edges is trained.
# A folder whose fits are not known exact (the noisy subject keeps true_params/) is refined by default.
for spec in "exact $EXACT" "noisy $NOISY --set model.pose_refinement.enabled=false" "noisy-refined $NOISY"; do
    read -r label subject flags <<<"$spec"
    variant "$label" "$subject" --set train.mask_edges=train ${flags:+$flags}
    if [ -f "$OUT/$label/refined_poses.json" ]; then
        python3 "$ROOT/scripts/ablation/pose_error.py" "$NOISY" "$OUT/$label" | sed "s/^/$label: /"
    fi
done
python3 "$ROOT/scripts/ablation/collect.py" --title "Body fits ($PRESET, noise $NOISE)" "${ROWS[@]}" \
    | tee "$OUT/table.md"
