#!/usr/bin/env bash
# Interleaves the Burn step benchmark (A) and its PyTorch twin (B), A B A B …, for each preset, and prints
# the median step time of each side and their ratio (Burn / PyTorch; below 1 means Burn is faster).
#
#   scripts/bench/compare.sh [presets (default: paper,cpu,tiny)] [rounds (default: 3)] [steps per run (default: 2)]
#
# Every run is a fresh process with one untimed warm-up step. Needs scripts/bench/.venv
# (scripts/bench/setup_torch.sh). Raw JSON lines go to target/bench/compare-<time>.jsonl.
set -euo pipefail
cd "$(dirname "$0")/../.."
presets="${1:-paper,cpu,tiny}"
rounds="${2:-3}"
steps="${3:-2}"
python="scripts/bench/.venv/bin/python"
[[ -x "$python" ]] || { echo "no $python: run scripts/bench/setup_torch.sh first" >&2; exit 1; }
cargo build --quiet -p anerf --bin anerf
anerf="${CARGO_TARGET_DIR:-target}/debug/anerf"
[[ -x "$anerf" ]] || anerf="target/debug/anerf"
mkdir -p target/bench
log="target/bench/compare-$(date +%Y%m%d-%H%M%S).jsonl"
for preset in ${presets//,/ }; do
    config="target/bench/$preset.json"
    "$anerf" bench --describe --presets "$preset" > "$config"
    for ((round = 1; round <= rounds; round++)); do
        echo "{\"side\": \"burn\", \"round\": $round, \"result\": $("$anerf" bench --presets "$preset" --steps "$steps" --render-size 0 --json)}" >> "$log"
        echo "{\"side\": \"torch\", \"round\": $round, \"result\": $("$python" scripts/bench/torch_reference.py --config "$config" --steps "$steps")}" >> "$log"
        echo "$preset round $round/$rounds done (load $(cut -d' ' -f1 /proc/loadavg))" >&2
    done
done
python3 - "$log" <<'EOF'
import json, statistics, sys
rows = [json.loads(line) for line in open(sys.argv[1])]
presets = list(dict.fromkeys(r["result"]["preset"] for r in rows))
print(f"{'preset':<7} {'burn s':>8} {'torch s':>8} {'ratio':>6} {'burn cpu s':>10} {'torch cpu s':>11} {'cpu ratio':>9} "
      f"{'burn pts/s':>11} {'torch pts/s':>11} {'load':>10}  runs")
for p in presets:
    side = lambda s, key: [t for r in rows if r["side"] == s and r["result"]["preset"] == p for t in r["result"][key]]
    burn, torch = statistics.median(side("burn", "step_seconds")), statistics.median(side("torch", "step_seconds"))
    bcpu = statistics.median(side("burn", "step_cpu_seconds"))
    tcpu = statistics.median(side("torch", "step_cpu_seconds"))
    loads = [r["result"]["load_before"] for r in rows if r["result"]["preset"] == p]
    points = rows[0]["result"]["points"]
    print(f"{p:<7} {burn:>8.3f} {torch:>8.3f} {burn / torch:>6.2f} {bcpu:>10.2f} {tcpu:>11.2f} {bcpu / tcpu:>9.2f} "
          f"{points / burn:>11.0f} {points / torch:>11.0f} "
          f"{min(loads):>4.1f}–{max(loads):<4.1f}  {len(side('burn', 'step_seconds'))}+{len(side('torch', 'step_seconds'))} steps")
print(f"raw figures: {sys.argv[1]}")
EOF
