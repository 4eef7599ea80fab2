#!/usr/bin/env bash
# Paper Table 1: neural blend weight field vs. the SMPL blend weight field, novel poses of H36M S9
# (`--config` for another subject, `--quick` for the tiny synthetic subject).
source "$(dirname "$0")/common.sh"
run_variant neural novel-pose
run_variant smpl novel-pose --set model.neural_blend_weights=false
write_table "Blend weights"
