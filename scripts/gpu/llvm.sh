#!/usr/bin/env bash
# Sets up the LLVM that CubeCL's CUDA runtime links, from Debian's packages, so that a CUDA build of anerf
# links on a machine that reaches only the package registries.
#
# Why: cubecl-cuda depends on cubecl-llvm (not optional in CubeCL 0.11), whose build dependency
# tracel-llvm-bundler downloads a prebuilt LLVM 23 from GitHub into
# <data_local_dir>/tracel/tracel-llvm-<version> (~/.local/share/... on Linux) unless the marker file
# `.tracel-llvm-installed` is there; with the marker it downloads nothing and runs `<prefix>/bin/llvm-config
# --link-static <arg>` for include folder, libraries and system libraries. Debian bookworm ships LLVM 22,
# which serves: this script installs it, writes the marker and puts an `llvm-config` wrapper at the prefix.
# The wrapper rewrites absolute library paths in `--system-libs` (Debian's LLVM names /usr/lib/.../libz3.so)
# to `-l` flags: the bundler takes a path's file stem as the library name and would ask the linker for
# `-llibz3`.
#
# Idempotent: a second run installs nothing and rewrites nothing (it prints "unchanged").
#
# usage: scripts/gpu/llvm.sh [--print-prefix]
# environment:
#   TRACEL_LLVM_VERSION  the bundler's version, as in Cargo.lock (default: read from Cargo.lock)
#   LLVM_MAJOR           Debian's LLVM to use (default 22)
#   XDG_DATA_HOME        where the bundler looks (default ~/.local/share, as the `dirs` crate reads it)
#   LLVM_CONFIG          an llvm-config to wrap instead of Debian's (nothing is installed then; the tests
#                        use a stand-in)
set -euo pipefail
cd "$(dirname "$0")/../.."

major=${LLVM_MAJOR:-22}
version=${TRACEL_LLVM_VERSION:-$(awk '/^name = "tracel-llvm-bundler"$/ {getline; gsub(/version = |"/, ""); print; exit}' Cargo.lock)}
if [ -z "$version" ]; then
    echo "error: Cargo.lock names no tracel-llvm-bundler (is the cuda feature's dependency tree locked?)" >&2
    exit 1
fi
prefix="${XDG_DATA_HOME:-$HOME/.local/share}/tracel/tracel-llvm-$version"
if [ "${1:-}" = --print-prefix ]; then
    echo "$prefix"
    exit 0
fi

real=${LLVM_CONFIG:-/usr/lib/llvm-$major/bin/llvm-config}
packages="llvm-$major-dev libpolly-$major-dev libzstd-dev libz3-dev"
if [ -n "${LLVM_CONFIG:-}" ]; then
    [ -x "$real" ] || { echo "error: LLVM_CONFIG=$real is not an executable" >&2; exit 1; }
elif [ ! -x "$real" ] || ! dpkg -s $packages >/dev/null 2>&1; then
    if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
        echo "error: $real is missing; install Debian's $packages (needs root and apt-get)" >&2
        exit 1
    fi
    echo "installing $packages"
    DEBIAN_FRONTEND=noninteractive apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $packages >/dev/null
fi

wrapper=$(cat <<EOF
#!/bin/sh
# Written by anerf's scripts/gpu/llvm.sh: $real standing in for tracel-llvm $version.
# Absolute library paths become -l flags (the bundler would turn /x/libz3.so into -llibz3).
"$real" "\$@" | sed -E 's#(^| )/[^ ]*/lib([A-Za-z0-9_+.-]+)\\.(so|a)(\\.[0-9.]+)?( |\$)#\\1-l\\2\\5#g'
EOF
)
changed=0
mkdir -p "$prefix/bin"
if [ ! -f "$prefix/bin/llvm-config" ] || [ "$(cat "$prefix/bin/llvm-config")" != "$wrapper" ]; then
    printf '%s\n' "$wrapper" >"$prefix/bin/llvm-config.tmp"
    chmod +x "$prefix/bin/llvm-config.tmp"
    mv "$prefix/bin/llvm-config.tmp" "$prefix/bin/llvm-config"
    changed=1
fi
if [ ! -f "$prefix/.tracel-llvm-installed" ]; then
    echo "$real via anerf scripts/gpu/llvm.sh" >"$prefix/.tracel-llvm-installed"
    changed=1
fi

# The wrapper must answer what the bundler asks, with no absolute library path left.
libs=$("$prefix/bin/llvm-config" --link-static --system-libs)
if printf '%s\n' "$libs" | tr ' ' '\n' | grep -q '^/'; then
    echo "error: $prefix/bin/llvm-config still names a library by path: $libs" >&2
    exit 1
fi
"$prefix/bin/llvm-config" --link-static --libs >/dev/null
if [ "$changed" = 1 ]; then
    echo "set up: $real at $prefix"
else
    echo "unchanged: $real at $prefix"
fi
