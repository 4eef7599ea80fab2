#!/usr/bin/env bash
# The baked avatar against its teacher (issue 37): one synthetic subject trained with the `fast` preset
# (stage 1, stage 2, the three splits), then `anerf bake` and the same three splits on the Gaussians, and
# `anerf bench --run` timing both renderers at 512² in turns. Prints the table (NeRF and baked rows), the
# bake's time, Gaussian count and size, and the frames per second.
#
# Bake flags come from BAKE_FLAGS (e.g. BAKE_FLAGS="--iterations 1500 --budget 30000").
#
# Usage: baked.sh [--preset demo|realistic] [--iterations N] [--out <folder>] [--seed N] [-- <train flags>]
# Defaults: the demo subject, the preset's schedule, runs/ablation/baked.
NOISE=0
USAGE_NOISE="(unused)"
source "$(dirname "${BASH_SOURCE[0]}")/synthetic_pair.sh"

variant nerf "$EXACT"
RUN="$OUT/nerf"
read -r -a BAKE <<< "${BAKE_FLAGS:-}"
start=$SECONDS
"$ANERF" bake "$RUN" --quiet --overwrite "${BAKE[@]}"
bake_seconds=$((SECONDS - start))
for split in training-view novel-view novel-pose; do
    "$ANERF" eval "$RUN" --baked --split "$split" --quiet >/dev/null
done
"$ANERF" bench --run "$RUN" --presets fast --steps 0 --render-size 512 | tee "$OUT/bench.txt"
python3 "$ROOT/scripts/ablation/collect.py" --title "Avatar ($PRESET)" \
    "NeRF=$RUN" "baked Gaussians=$RUN/baked" | tee "$OUT/table.md"
python3 - "$RUN/baked" "$bake_seconds" <<'PY' | tee -a "$OUT/table.md"
import json, os, sys
folder, seconds = sys.argv[1], sys.argv[2]
avatar = json.load(open(os.path.join(folder, "avatar.json")))
size = sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder)
           if os.path.isfile(os.path.join(folder, f)))
print(f"\nbake: {seconds} s, {avatar['gaussians']} Gaussians, {size / 2**20:.1f} MiB in {folder}")
PY
