#!/usr/bin/env bash
# Builds, on a CPU machine, what scripts/gpu/device_check.sh runs on a GPU machine without a Rust toolchain:
# target/gpu-bundle/anerf (release, features cuda and wgpu, stripped) and target/gpu-bundle/gpu_kernels,
# which runs anerf-core's GPU-vs-flex comparisons (the hash-grid CubeCL kernels, the full model's render and
# gradients, an MLP, skinning and the volume lookup) from the two test binaries beside it. No CUDA toolkit
# is needed: cudarc loads the driver and NVRTC at run time (.cargo/config.toml pins the API version).
# Refuses a bundle over 60 MiB (what the device machine takes).
#
# usage: scripts/gpu/bundle.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
out=target/gpu-bundle
rm -rf "$out"
mkdir -p "$out"

cargo build --release -p anerf-train --bin anerf --features anerf-core/cuda,anerf-core/wgpu
strip -o "$out/anerf" target/release/anerf

# The comparisons: anerf-core's unit tests (selected by name when run) and the gpu_backends test.
cargo test --release -p anerf-core --features cuda,wgpu --lib --test gpu_backends --no-run \
    --message-format=json >"$out/artifacts.json"
python3 - "$out" <<'PY'
import json, pathlib, subprocess, sys
out = pathlib.Path(sys.argv[1])
found = {}
for line in (out / "artifacts.json").read_text().splitlines():
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable"):
        found[m["target"]["name"]] = m["executable"]
for name, bundled in [("anerf_core", "core_tests"), ("gpu_backends", "gpu_backends")]:
    if name not in found:
        sys.exit(f"error: cargo built no test binary {name} (built: {sorted(found)})")
    subprocess.run(["strip", "-o", str(out / bundled), found[name]], check=True)
(out / "artifacts.json").unlink()
PY

# What device_check.sh runs: only the GPU comparisons (the CPU tests ran where this was built).
cat >"$out/gpu_kernels" <<'SH'
#!/usr/bin/env bash
here=$(dirname "$0")
status=0
"$here/core_tests" cube_tests flex_and_gpu_backends "$@" || status=1
"$here/gpu_backends" "$@" || status=1
exit $status
SH
chmod +x "$out/gpu_kernels"

size=$(du -sm "$out" | cut -f1)
ls -la "$out"
if [ "$size" -gt 60 ]; then
    echo "error: the bundle is $size MiB, over 60 MiB" >&2
    exit 1
fi
echo "bundle: $out ($size MiB)"
