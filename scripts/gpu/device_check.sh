#!/usr/bin/env bash
# The GPU device check: one prepared script for a machine with an NVIDIA GPU, CUDA's driver and PyTorch but
# no Rust toolchain. Given the bundle scripts/gpu/bundle.sh makes on a CPU machine (a stripped release
# `anerf` built with the cuda and wgpu features, the GPU kernel test binaries and the Vulkan loader; as the
# folder target/gpu-bundle or the archive target/gpu-bundle.tar.xz, which it unpacks), it runs, in this order
# of importance,
#
#   1. the GPU-vs-flex kernel tests (values and gradients; each backend skipped with its reason when absent),
#   2. `anerf bench` on the first device of DEVICES for the `fast` and `paper` presets (a 512² render with
#      `fast`),
#   3. scripts/bench/torch_reference.py on the same networks and device (when PyTorch is there),
#   4. the demo end to end on the first device, then its trained model's 512² render (cold and warm) and
#      CubeCL kernel profiles of that render and of 60 training steps,
#   5. data-parallel training (`anerf train --devices`, Burn's all-reduce; on cuda:0, or cuda:0,cuda:1 where
#      two GPUs exist) against one-device training of the same seed, run twice: the runs' first losses,
#   6. the trained demo baked into Gaussians on the first device (1,000 steps), and its 512² render beside
#      the NeRF's,
#   7. `anerf bench` on the other devices of DEVICES,
#
# and writes figures.json (every figure, the GPU's name, the adapter each device ran on) and check.log into
# OUT. Each step has a time limit and the whole check a deadline (a step that would start past it is skipped
# with that reason); a failed step is recorded, not fatal, so one run brings back everything that worked.
#
# Libraries: where the dynamic loader finds no NVRTC, the CUDA toolkit's or PyTorch's copy is added to
# LD_LIBRARY_PATH; where it finds no Vulkan loader, the bundle's vulkan/ is; where Vulkan's default search finds
# no driver manifest, VK_DRIVER_FILES points at the NVIDIA ICD. env.json records what was added.
#
# usage: scripts/gpu/device_check.sh OUT
# environment:
#   BUNDLE    folder with `anerf` and `gpu_kernels`, or a .tar.xz of one (default: target/gpu-bundle, else
#             target/gpu-bundle.tar.xz)
#   DEVICES   devices to measure, the first one also runs the demo (default: "cuda wgpu")
#   PRESETS   bench presets (default: "fast paper"); POINTS, STEPS: points per step, timed steps
#   DEMO      1 to run the demo (default 1); PYTHON: the interpreter with torch (default python3)
#   DEADLINE  seconds the whole check may take (default 480)
# On a machine without a GPU (DEVICES=flex) the same steps run on the CPU: that is how the script itself is
# tested (apps/anerf/tests/device_check.rs).
set -uo pipefail
cd "$(dirname "$0")/../.."

out=${1:?usage: $0 OUT}
bundle=${BUNDLE:-}
if [ -z "$bundle" ]; then
    bundle=target/gpu-bundle
    [ ! -x "$bundle/anerf" ] && [ -f target/gpu-bundle.tar.xz ] && bundle=target/gpu-bundle.tar.xz
fi
deadline=$(( $(date +%s) + ${DEADLINE:-480} ))
devices=${DEVICES:-cuda wgpu}
presets=${PRESETS:-fast paper}
points=${POINTS:-65536}
steps=${STEPS:-5}
demo=${DEMO:-1}
python=${PYTHON:-python3}

mkdir -p "$out"
log="$out/check.log"
steps_file="$out/steps.jsonl"
: >"$log"
: >"$steps_file"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

say() { echo "[$(date +%H:%M:%S)] $*" | tee -a "$log" >&2; }

# Records a step that could not run here, with why.
skipped() {
    say "skip $1: $2"
    printf '{"step": "%s", "outcome": "skipped", "reason": "%s", "status": 0, "seconds": 0, "output": ""}\n' \
        "$1" "$2" >>"$steps_file"
}

# Runs one step under a time limit (cut to what the deadline leaves): `step NAME LIMIT_S OUTPUT_FILE
# command...`. The command's stdout goes to OUTPUT_FILE, its stderr to the log; a line of steps.jsonl records
# name, status and seconds.
step() {
    local name=$1 limit=$2 output=$3
    shift 3
    local left=$(( deadline - $(date +%s) ))
    if [ "$left" -lt 15 ]; then
        skipped "$name" "out of time: the check's deadline has passed"
        return 1
    fi
    [ "$limit" -gt "$left" ] && limit=$left
    say "start $name (limit $limit s): $*"
    local start status
    start=$(date +%s%N)
    timeout --kill-after=10 "$limit" "$@" >"$output" 2>>"$log"
    status=$?
    local ms=$(( ($(date +%s%N) - start) / 1000000 ))
    local seconds
    seconds=$(printf '%d.%03d' $((ms / 1000)) $((ms % 1000)))
    local outcome=passed
    [ $status -eq 124 ] || [ $status -eq 137 ] && outcome=timed_out
    [ $status -ne 0 ] && [ "$outcome" = passed ] && outcome=failed
    printf '{"step": "%s", "outcome": "%s", "status": %d, "seconds": %s, "output": "%s"}\n' \
        "$name" "$outcome" "$status" "$seconds" "$(basename "$output")" >>"$steps_file"
    say "end $name: $outcome (status $status) in ${seconds%.*} s"
    return $status
}

if [ -f "$bundle" ]; then
    say "unpacking $bundle"
    mkdir -p "$work/bundle"
    if ! xz -dc "$bundle" | tar -C "$work/bundle" -xf -; then
        say "error: cannot unpack $bundle (expected the .tar.xz scripts/gpu/bundle.sh writes)"
        exit 1
    fi
    bundle=$work/bundle
fi
anerf="$bundle/anerf"
kernels="$bundle/gpu_kernels"
if [ ! -x "$anerf" ]; then
    say "error: no anerf binary at $anerf (make the bundle with scripts/gpu/bundle.sh, or set BUNDLE)"
    exit 1
fi

# Libraries the binary loads at run time, where the machine's dynamic loader does not find them.
has_lib() {
    ldconfig -p 2>/dev/null | awk '{print $1}' | grep -q "^$1" && return 0
    local dir
    for dir in ${LD_LIBRARY_PATH//:/ }; do
        ls "$dir/$1"* >/dev/null 2>&1 && return 0
    done
    return 1
}
added=()
if ! has_lib libnvrtc.so; then
    nvidia_dirs=$("$python" -c 'import glob, os, nvidia
print(" ".join(sorted({os.path.dirname(p) for d in nvidia.__path__ for p in glob.glob(d + "/**/libnvrtc.so*", recursive=True)})))' 2>/dev/null)
    for dir in /usr/local/cuda/lib64 /usr/local/cuda/targets/x86_64-linux/lib $nvidia_dirs; do
        if ls "$dir"/libnvrtc.so* >/dev/null 2>&1; then
            export LD_LIBRARY_PATH="$dir${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
            added+=("nvrtc from $dir")
            break
        fi
    done
fi
if ! has_lib libvulkan.so.1 && [ -d "$bundle/vulkan" ]; then
    export LD_LIBRARY_PATH="$(cd "$bundle/vulkan" && pwd)${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    added+=("vulkan loader from the bundle")
fi
if [ -z "${VK_DRIVER_FILES:-}${VK_ICD_FILENAMES:-}" ] \
    && ! ls /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then
    for icd in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/nvidia/nvidia_icd.json; do
        if [ -f "$icd" ]; then
            export VK_DRIVER_FILES=$icd
            added+=("vulkan driver $icd")
            egl=${icd%/vulkan/icd.d/nvidia_icd.json}/glvnd/egl_vendor.d/10_nvidia.json
            [ -f "$egl" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$egl
            break
        fi
    done
fi
python3 - "${added[@]}" >"$out/env.json" <<'EOF'
import json, os, sys
print(json.dumps({"added": sys.argv[1:], "LD_LIBRARY_PATH": os.environ.get("LD_LIBRARY_PATH"),
                  "VK_DRIVER_FILES": os.environ.get("VK_DRIVER_FILES")}))
EOF
say "libraries: ${added[*]:-none added}"

# The machine.
{
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
} >"$out/gpu.txt"
say "GPU: $(head -1 "$out/gpu.txt"); CPU: $(nproc) cores"

# 1. Kernel tests against flex (the test binary skips a backend that is not there, naming why).
if [ -x "$kernels" ]; then
    step kernel_tests 120 "$out/kernel_tests.txt" "$kernels" --test-threads=1 --nocapture
else
    skipped kernel_tests "no test binary at $kernels"
fi

# 2. Benchmarks: one process per device and preset (a failure on one leaves the others).
bench() {
    local device=$1 preset render
    for preset in $presets; do
        render=0
        [ "$preset" = fast ] && render=512
        step "bench_${device}_${preset}" 120 "$out/bench_${device}_${preset}.json" \
            "$anerf" bench --device "$device" --presets "$preset" --points "$points" --steps "$steps" \
            --render-size "$render" --subject "$work/subject" --json
    done
}
first=${devices%% *}
bench "$first"

# 3. PyTorch on the same networks and device.
torch_device=$first
[ "$first" = wgpu ] && torch_device=cuda
if "$python" -c "import torch" 2>/dev/null; then
    for preset in $presets; do
        "$anerf" bench --describe --presets "$preset" >"$work/$preset.json" 2>>"$log"
        step "torch_${torch_device}_${preset}" 90 "$out/torch_${torch_device}_${preset}.json" \
            "$python" scripts/bench/torch_reference.py --config "$work/$preset.json" --device "$torch_device" \
            --points "$points" --steps "$steps"
    done
else
    skipped torch "$python has no torch"
fi

# A profiled anerf command: `profile NAME args...` runs `anerf args...` with CubeCL's kernel log and writes
# the per-kernel summary to OUT/profile_NAME.txt (the log itself, megabytes, stays in the work folder).
profile() {
    local name=$1
    shift
    step "profile_$name" 90 "$work/profile_$name.out" env CUBECL_DEBUG_LOG="$work/profile_$name.log" "$anerf" "$@"
    python3 scripts/gpu/kernel_profile.py "$work/profile_$name.log" --top 40 >"$out/profile_$name.txt" 2>>"$log"
}

# 4. The demo end to end on the first device (its plain progress lines go to the log).
if [ "$demo" = 1 ]; then
    step "demo_${first}" 180 "$out/demo_${first}.txt" "$anerf" demo --device "$first" --out "$work/demo"
    cp "$work/demo/run/eval/novel-view/summary.json" "$out/demo_novel_view.json" 2>/dev/null
    cp "$work/demo/run/eval/novel-pose/summary.json" "$out/demo_novel_pose.json" 2>/dev/null
    # The trained demo's 512² render, cold and warm, and where a warm render's and a training step's device
    # time goes: CubeCL's per-kernel log (synchronised after each kernel), summed by kernel_profile.py.
    if [ -d "$work/demo/run" ]; then
        step "render_trained_${first}" 60 "$out/render_trained_${first}.json" \
            "$anerf" bench --device "$first" --run "$work/demo/run" --steps 0 --render-size 512 --json
        profile render bench --device "$first" --run "$work/demo/run" --steps 0 --render-size 512 --json
        profile stage1 train configs/demo.toml --device "$first" --set "dataset.root=$work/demo/subject" \
            --set "dataset.cache=$work/demo/cache" --iterations 60 --quiet --set train.log_every=20 \
            --out "$work/profile_run"
    fi
fi

# 5. Data-parallel training against one device, the same seed: the first steps' losses must agree.
if [ "$first" = cuda ]; then
    parallel=cuda:0
    [ "$(nvidia-smi -L 2>/dev/null | wc -l)" -ge 2 ] && parallel=cuda:0,cuda:1
    [ -d "$work/ddp_subject" ] || "$anerf" synth --preset tiny --out "$work/ddp_subject" 2>>"$log"
    # A command line, not a shell function: `timeout` runs programs only.
    short_run=("$anerf" train --data "$work/ddp_subject" --preset tiny --iterations 6 --quiet
        --set train.log_every=1)
    step ddp_one_device 90 "$work/ddp_one.txt" "${short_run[@]}" --device cuda --out "$work/ddp_one"
    # The same one-device run again: how far two runs of one seed differ on this GPU.
    step ddp_one_again 90 "$work/ddp_again.txt" "${short_run[@]}" --device cuda --out "$work/ddp_again"
    step ddp_parallel 90 "$work/ddp_parallel.txt" "${short_run[@]}" --devices "$parallel" \
        --out "$work/ddp_parallel"
    python3 - "$work" "$parallel" >"$out/ddp.json" 2>>"$log" <<'EOF'
import json, pathlib, sys
work, devices = pathlib.Path(sys.argv[1]), sys.argv[2]
def losses(run):
    log = work / run / "metrics.jsonl"
    if not log.is_file():
        return []
    return [json.loads(l)["loss"] for l in log.read_text().splitlines() if l.strip()]
def worst(a, b):
    return max((abs(x - y) / max(abs(x), 1e-12) for x, y in zip(a, b)), default=None)
one, again, parallel = losses("ddp_one"), losses("ddp_again"), losses("ddp_parallel")
print(json.dumps({"devices": devices, "one_device": one, "one_device_again": again, "parallel": parallel,
                  "worst_relative": worst(one, parallel), "worst_relative_again": worst(one, again)}))
EOF
else
    skipped ddp "data-parallel training needs cuda as the first of DEVICES (Burn 0.22.1 all-reduces on CUDA only)"
fi

# 6. The demo's avatar baked into Gaussians on the first device (the step's seconds are the bake's time on
# this GPU), then `bench --run`, which draws a run's baked Gaussians beside its NeRF.
if [ "$demo" = 1 ] && [ -d "$work/demo/run" ]; then
    step "bake_${first}" 90 "$out/bake_${first}.txt" \
        "$anerf" bake "$work/demo/run" --device "$first" --iterations 1000 --quiet
    step "render_baked_${first}" 60 "$out/render_baked_${first}.json" \
        "$anerf" bench --device "$first" --run "$work/demo/run" --steps 0 --render-size 512 --json
fi

# 7. The other devices' benchmarks.
for device in ${devices#"$first"}; do
    bench "$device"
done

# One JSON of everything (Python's standard library only).
python3 - "$out" <<'EOF'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
def read(name):
    path = out / name
    if not name or not path.is_file():
        return None
    text = path.read_text().strip()
    try:
        return json.loads(text.splitlines()[-1]) if text else None
    except (json.JSONDecodeError, IndexError):
        return text[-4000:]
steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines() if line.strip()]
for s in steps:
    s["result"] = read(s.get("output", ""))
figures = {
    "gpu": (out / "gpu.txt").read_text().strip(),
    "libraries": read("env.json"),
    "steps": steps,
    "demo": {"novel_view": read("demo_novel_view.json"), "novel_pose": read("demo_novel_pose.json")},
    "data_parallel": read("ddp.json"),
}
(out / "figures.json").write_text(json.dumps(figures, indent=1))
failed = [s["step"] for s in steps if s["outcome"] not in ("passed", "skipped")]
print(f"figures in {out / 'figures.json'}; {len(steps)} steps, failed: {', '.join(failed) or 'none'}")
EOF
