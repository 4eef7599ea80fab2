#!/usr/bin/env bash
# Packs a bundle folder into one .tar.xz for the GPU machine and refuses it over the size limit (what the
# device machine takes beside the working tree), leaving no archive then. One xz stream with a dictionary
# larger than a binary: the bundle's executables share most of their code (Burn, CubeCL, LLVM), which a
# small dictionary would compress once per executable.
#
# usage: scripts/gpu/pack.sh FOLDER ARCHIVE
# environment: LIMIT_MIB  the size limit (default 60)
set -euo pipefail
folder=${1:?usage: $0 FOLDER ARCHIVE}
archive=${2:?usage: $0 FOLDER ARCHIVE}
limit=${LIMIT_MIB:-60}
rm -f "$archive"
tar -C "$folder" -cf - . | xz -T1 --lzma2=preset=6,dict=512MiB >"$archive.tmp"
bytes=$(stat -c %s "$archive.tmp")
if [ "$bytes" -gt $((limit * 1048576)) ]; then
    rm -f "$archive.tmp"
    echo "error: the bundle of $folder packs to $((bytes / 1048576)) MiB, over the $limit MiB limit" >&2
    exit 1
fi
mv "$archive.tmp" "$archive"
echo "bundle: $archive ($((bytes / 1048576)) MiB)"
