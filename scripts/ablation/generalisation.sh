#!/usr/bin/env bash
# The held-out-view gap (docs/QUALITY.md): the model changes A/B'd on the realistic built-in subject
# (`--config` for another subject, e.g. configs/synthetic/realistic-exact.toml or configs/demo.toml;
# `--quick` for the tiny one), each trained, animated and evaluated on the training views, the held-out views
# and the novel poses. Make the subject first: anerf synth --preset realistic --out data/synthetic/realistic
DEFAULT_CONFIG="$(cd "$(dirname "$0")/../.." && pwd)/configs/synthetic/realistic.toml"
source "$(dirname "$0")/common.sh"
# The authors' choices on the fast preset's model, then one change each; then the preset as it ships and
# with each of its own choices undone.
AUTHORS=(--set 'model.residual_init="random"' --set 'model.view_direction="world"' --set train.mask_weight=0)
run_variant authors all "${AUTHORS[@]}"
run_variant zero_residual all "${AUTHORS[@]}" --set 'model.residual_init="zero"'
run_variant canonical_dirs all "${AUTHORS[@]}" --set 'model.view_direction="canonical"'
run_variant no_view_dependence all "${AUTHORS[@]}" --set 'model.view_direction="none"'
run_variant fast all
run_variant fast_random_residual all --set 'model.residual_init="random"'
run_variant fast_without_silhouette all --set train.mask_weight=0
write_table "Variant"
