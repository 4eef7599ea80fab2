#!/usr/bin/env bash
# Runs the wgpu-vs-flex comparison tests and the CubeCL kernels' tests on Mesa's lavapipe (software Vulkan)
# without installing it: the Debian packages (Mesa 25 from bookworm-backports by default) and the Vulkan
# loader are downloaded and unpacked under a prefix (default /opt/mesa25), and the loader is pointed at them
# for these commands only. See docs/PERFORMANCE.md, "GPU backends".
#
#   scripts/gpu/lavapipe.sh                 # set up (once), then run the gated tests on it
#   scripts/gpu/lavapipe.sh --env           # set up, then only print the variables, e.g. for
#   eval "$(scripts/gpu/lavapipe.sh --env)"; cargo run --features anerf-core/wgpu -- train ... --device wgpu
#   scripts/gpu/lavapipe.sh --release bookworm --prefix /opt/mesa22   # bookworm's own Mesa 22.3
#
# Needs apt with the release in its sources (no root: `apt-get download` and `dpkg -x` only) and an x86_64
# machine. The system's own Mesa is left alone.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
PREFIX=/opt/mesa25
RELEASE=bookworm-backports
ENV_ONLY=0
usage() {
    echo "usage: $0 [--prefix <folder>] [--release <suite>] [--env]" >&2
    exit 2
}
while [ $# -gt 0 ]; do
    case "$1" in
        --prefix) PREFIX="$2"; shift ;;
        --release) RELEASE="$2"; shift ;;
        --env) ENV_ONLY=1 ;;
        *) usage ;;
    esac
    shift
done

LIB="$PREFIX/usr/lib/x86_64-linux-gnu"
ICD="$PREFIX/lvp_icd.x86_64.json"
if [ ! -f "$LIB/libvulkan_lvp.so" ]; then
    # Mesa 25.0 from backports needs a newer libdrm than bookworm's (>= 2.4.121); its LLVM (libllvm15) and
    # the other libraries are bookworm's own. The loader (libvulkan1) comes along: a fresh machine may lack it.
    debs="$(mktemp -d)"
    trap 'rm -rf "$debs"' EXIT
    (cd "$debs" && apt-get download -t "$RELEASE" mesa-vulkan-drivers libdrm2 libdrm-amdgpu1 >&2 \
        && apt-get download libvulkan1 >&2)
    mkdir -p "$PREFIX"
    for deb in "$debs"/*.deb; do
        dpkg -x "$deb" "$PREFIX"
    done
fi
# The packaged manifest names the library without a path (it expects the system's library folder): the same
# manifest, its Vulkan version kept, with the unpacked library's path.
sed "s|\"library_path\": *\"[^\"]*\"|\"library_path\": \"$LIB/libvulkan_lvp.so\"|" \
    "$PREFIX/usr/share/vulkan/icd.d/lvp_icd.x86_64.json" > "$ICD.tmp"
mv "$ICD.tmp" "$ICD"

export VK_ICD_FILENAMES="$ICD"
export LD_LIBRARY_PATH="$LIB${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
if [ "$ENV_ONLY" = 1 ]; then
    echo "export VK_ICD_FILENAMES='$VK_ICD_FILENAMES'"
    echo "export LD_LIBRARY_PATH='$LD_LIBRARY_PATH'"
    exit 0
fi

# The tests skip (and pass) where wgpu has no working adapter; here they must run, on this Mesa.
version="$(zcat "$PREFIX/usr/share/doc/mesa-vulkan-drivers/changelog.Debian.gz" | head -1 | sed 's/^mesa (\([^)]*\)).*/\1/')"
cd "$ROOT"
log="$(mktemp)"
for filter in "--test gpu_backends" "--lib flex_and_gpu_backends" "--lib cube_"; do
    # shellcheck disable=SC2086 # $filter is two words on purpose
    CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-1}" cargo test -p anerf-core --features wgpu $filter -- --nocapture \
        2>&1 | grep -v XDG_RUNTIME_DIR | tee -a "$log"
done
# The adapter names Mesa's own version (the backports' with their Debian revision, bookworm's without).
ran="$(grep -c "^running .* on wgpu (Vulkan: .*Mesa ${version%%-*}" "$log" || true)"
skipped="$(grep -c "^skipping .* on wgpu" "$log" || true)"
rm -f "$log"
if [ "$ran" -eq 0 ] || [ "$skipped" -ne 0 ]; then
    echo "the comparisons were to run on lavapipe, Mesa $version: $ran did, $skipped skipped" >&2
    exit 1
fi
echo "$ran GPU tests (wgpu-vs-flex comparisons, CubeCL kernels) passed on lavapipe, Mesa $version"
