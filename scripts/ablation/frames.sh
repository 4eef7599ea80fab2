#!/usr/bin/env bash
# Paper Table 3: models trained on 1, 100, 200 and 800 video frames of H36M S9 (every 5th raw frame), tested
# on the same novel poses (`--quick`: 1, 2, 4 and 6 frames of the tiny synthetic subject).
source "$(dirname "$0")/common.sh"
if [ "$QUICK" = 1 ]; then COUNTS="1 2 4 6"; STEP=1; else COUNTS="1 100 200 800"; STEP=5; fi
for n in $COUNTS; do
    run_variant "frames_$n" novel-pose --set "dataset.iccv.train_frames=\"0:$((n * STEP))\""
done
write_table "Frames"
