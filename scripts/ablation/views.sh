#!/usr/bin/env bash
# Paper Table 4: models trained on 1, 2 and 3 camera views (H36M S9 tests on camera 3 and trains on cameras
# 0, 1, 2 — the first n of them; `--quick`: cameras 0, 2, 3 of the tiny synthetic subject, test camera 1).
source "$(dirname "$0")/common.sh"
if [ "$QUICK" = 1 ]; then VIEWS=(0 2 3); TEST=1; else VIEWS=(0 1 2); TEST=3; fi
for n in 1 2 3; do
    list=$(IFS=,; echo "${VIEWS[*]:0:$n}")
    run_variant "views_$n" novel-pose --set "dataset.train_views=[$list]" --set "dataset.test_views=[$TEST]"
done
write_table "Views"
