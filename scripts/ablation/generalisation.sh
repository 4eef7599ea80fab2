#!/usr/bin/env bash
# The held-out-view gap (docs/QUALITY.md): the model changes A/B'd on the realistic built-in subject
# (`--config` for another subject, e.g. configs/synthetic/realistic-exact.toml or configs/demo.toml;
# `--quick` for the tiny one), each trained, animated and evaluated on the training views, the held-out views
# and the novel poses. Make the subject first: anerf synth --preset realistic --out data/synthetic/realistic
DEFAULT_CONFIG="$(cd "$(dirname "$0")/../.." && pwd)/configs/synthetic/realistic.toml"
source "$(dirname "$0")/common.sh"
AUTHORS=(--set 'model.residual_init="random"' --set 'model.view_direction="world"')
run_variant authors all "${AUTHORS[@]}"
run_variant zero_residual all "${AUTHORS[@]}" --set 'model.residual_init="zero"'
run_variant canonical_dirs all "${AUTHORS[@]}" --set 'model.view_direction="canonical"'
run_variant no_view_dependence all "${AUTHORS[@]}" --set 'model.view_direction="none"'
write_table "Variant"
