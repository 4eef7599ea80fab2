# Shared by the ablation drivers: argument parsing, the anerf binary, quick mode, and running one variant.
# Sourced, not run. Each driver defines its variants and calls `run_variant <label> <split> [--set …]`.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
QUICK=0
CONFIG=""
OUT=""
usage() {
    echo "usage: $0 [--quick] [--config <experiment.toml>] [--out <folder>]" >&2
    echo "  --quick   run on the tiny synthetic subject with a tiny model (minutes on a CPU)" >&2
    exit 2
}
while [ $# -gt 0 ]; do
    case "$1" in
        --quick) QUICK=1 ;;
        --config) CONFIG="$2"; shift ;;
        --out) OUT="$2"; shift ;;
        *) usage ;;
    esac
    shift
done

ANERF="${ANERF:-$ROOT/target/debug/anerf}"
if [ ! -x "$ANERF" ]; then
    (cd "$ROOT" && cargo build -q -p anerf)
fi

if [ "$QUICK" = 1 ]; then
    OUT="${OUT:-$ROOT/runs/ablation-quick/$(basename "$0" .sh)}"
    mkdir -p "$OUT"
    SUBJECT="$OUT/../tiny-subject"
    [ -f "$SUBJECT/annots.npy" ] || "$ANERF" synth --preset tiny --out "$SUBJECT" >/dev/null
    CONFIG="$OUT/quick.toml"
    cat > "$CONFIG" <<TOML
name = "quick"
[dataset]
format = "zju_mocap"
root = "$SUBJECT"
cache = "$OUT/../cache"
ratio = 1.0
train_views = [0, 2]
iccv = { train_frames = "0:6", novel_pose_frames = "6:10" }
[model]
preset = "tiny"
[train]
iterations = 30
batch = 256
checkpoint_every = 1000
validate_every = 0
log_every = 10
[animate]
iterations = 5
batch = 2048
log_every = 5
[eval]
frame_interval = 2
chunk = 4096
TOML
else
    [ -n "$CONFIG" ] || CONFIG="${DEFAULT_CONFIG:-$ROOT/configs/h36m/S9.toml}"
    OUT="${OUT:-$ROOT/runs/ablation/$(basename "$0" .sh)}"
    mkdir -p "$OUT"
fi

ROWS=()

# run_variant <label> <split: novel-view|novel-pose|all> [--set key=value ...]: trains (both stages for
# novel-pose and all) and evaluates one variant into $OUT/<label>, and remembers its summary for the table
# (`all`: the training-view, novel-view and novel-pose splits, side by side). A variant run again replaces its
# earlier run.
run_variant() {
    local label="$1" split="$2"
    shift 2
    local run="$OUT/$label"
    "$ANERF" train "$CONFIG" --quiet --overwrite --out "$run" "$@"
    if [ "$split" != novel-view ]; then
        "$ANERF" animate "$run" --quiet
    fi
    if [ "$split" = all ]; then
        for s in training-view novel-view novel-pose; do
            "$ANERF" eval "$run" --split "$s" --quiet >/dev/null
        done
        ROWS+=("$label=$run")
    else
        "$ANERF" eval "$run" --split "$split" --quiet >/dev/null
        ROWS+=("$label=$run/eval/$split/summary.json")
    fi
}

# write_table <title>: the Markdown table of every variant run so far, printed and saved as $OUT/table.md.
write_table() {
    python3 "$ROOT/scripts/ablation/collect.py" --title "$1" "${ROWS[@]}" | tee "$OUT/table.md"
}
