#!/usr/bin/env bash
# Builds, on a CPU machine, what scripts/gpu/device_check.sh runs on a GPU machine without a Rust toolchain,
# packed as one archive, target/gpu-bundle.tar.xz, holding:
#   anerf          release, features cuda and wgpu, stripped;
#   core_tests, gpu_backends, gpu_kernels
#                  anerf-core's GPU-vs-flex comparisons (hash-grid and warp CubeCL kernels, the full model's
#                  render and gradients, an MLP, skinning, the volume lookup) and the script that runs them;
#   lib/           the shared libraries those link beyond glibc and the C++ runtime (LLVM's z3, libxml2, ICU),
#                  which the executables' wrapper scripts put on the library path;
#   vulkan/        the Vulkan loader and GLVND libraries (Debian's, unpacked with dpkg -x) that `--device wgpu`
#                  needs where the GPU machine has the NVIDIA driver but no loader.
# No CUDA toolkit is needed: cudarc loads the driver and NVRTC at run time (.cargo/config.toml pins the API
# version). Linking CubeCL's CUDA runtime needs LLVM, which scripts/gpu/llvm.sh sets up from Debian's
# packages (CubeCL's own build would download it). Refuses an archive over 60 MiB (what the device machine
# takes with the working tree).
#
# usage: scripts/gpu/bundle.sh
# environment: VULKAN_DEBS  a folder of .deb files to unpack into lib/ instead of downloading them with apt
set -euo pipefail
cd "$(dirname "$0")/../.."
out=target/gpu-bundle
archive=target/gpu-bundle.tar.xz
rm -rf "$out" "$archive"
mkdir -p "$out"

bash scripts/gpu/llvm.sh
cargo build --release -p anerf --bin anerf --features anerf-core/cuda,anerf-core/wgpu
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
"$here/core_tests" cube_tests cube_sort flex_and_gpu_backends "$@" || status=1
"$here/gpu_backends" "$@" || status=1
exit $status
SH
chmod +x "$out/gpu_kernels"

# Shared libraries the binaries link that a GPU machine's image may lack (LLVM's z3 and libxml2 with their
# ICU, of this machine's versions), in lib/, which the wrappers below put first on the library path; glibc
# and the C++ runtime stay the machine's.
mkdir -p "$out/lib"
for binary in "$out/anerf" "$out/core_tests" "$out/gpu_backends"; do
    ldd "$binary" | awk '$2 == "=>" && $3 ~ /^\// {print $3}'
done | sort -u | while read -r library; do
    case $(basename "$library") in
        libc.so*|libm.so*|libdl.so*|librt.so*|libpthread.so*|ld-linux*|libgcc_s.so*|libstdc++.so*) ;;
        *) cp -L "$library" "$out/lib/" ;;
    esac
done
for binary in anerf core_tests gpu_backends; do
    mv "$out/$binary" "$out/$binary.bin"
    cat >"$out/$binary" <<SH
#!/usr/bin/env bash
here=\$(cd "\$(dirname "\$0")" && pwd)
export LD_LIBRARY_PATH="\$here/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
exec "\$here/$binary.bin" "\$@"
SH
    chmod +x "$out/$binary"
done

# The Vulkan loader and GLVND, in vulkan/, for a GPU machine whose image lacks them (the NVIDIA driver
# brings its ICD, not the loader); device_check.sh adds the folder only where no loader is found.
debs=${VULKAN_DEBS:-}
if [ -z "$debs" ]; then
    debs=$(mktemp -d)
    trap 'rm -rf "$debs"' EXIT
    (cd "$debs" && apt-get download libvulkan1 libglvnd0 libegl1 libgl1 libglx0 libopengl0 >/dev/null)
fi
unpacked=$(mktemp -d)
for deb in "$debs"/*.deb; do
    dpkg -x "$deb" "$unpacked"
done
mkdir -p "$out/vulkan"
find "$unpacked" -name '*.so*' \( -type f -o -type l \) -exec cp -a {} "$out/vulkan/" \;
rm -rf "$unpacked"
if [ ! -e "$out/vulkan/libvulkan.so.1" ]; then
    echo "error: no libvulkan.so.1 among the unpacked packages in $debs" >&2
    exit 1
fi

ls -la "$out"
bash scripts/gpu/pack.sh "$out" "$archive"
