#!/usr/bin/env bash
# Copies the `subpixel` binary and the GPU-facing test binaries of a release build into
# BIN_DIR (stripped), for tools/gpu_check.sh on another machine.
#
#   cargo build --release && cargo test --release --no-run && tools/gpu_bins.sh BIN_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
dest=${1:?BIN_DIR}
mkdir -p "$dest"
cp target/release/subpixel "$dest/subpixel"
for t in kernels ssr_api ssr_golden render cpu_twin view; do
  # The newest test binary of that name (cargo names them NAME-HASH).
  f=$(ls -t target/release/deps/"$t"-* 2>/dev/null | grep -v '\.d$' | head -1)
  [ -n "$f" ] || { echo "no test binary for $t: run cargo test --release --no-run" >&2; exit 1; }
  cp "$f" "$dest/$t"
done
strip "$dest"/*
pwd > "$dest/built_in"
du -sh "$dest"
