#!/usr/bin/env bash
# Third call of the sixteenth session: the pooled levels read on load against pooling
# passes (SUBPIXEL_POOLING), the network at 1080p f32 with each, alternated, after one
# tuning (auto: its decision is logged). Carry .devpack/new (this build) and .devpack/.gl.
set -u
O=${1:?OUT}; mkdir -p "$O"
for f in .devpack/.gl/*.deb; do dpkg -x "$f" /; done; ldconfig
xz -dc .devpack/new/subpixel.xz > /tmp/subpixel && chmod +x /tmp/subpixel
. tools/gpu_env.sh
export SUBPIXEL_CACHE_DIR="$O/cache"
RUST_LOG=subpixel=info timeout 80 /tmp/subpixel bench denoise --width 1920 --height 1080 --precision f32 \
  --frames 30 > "$O/auto.log" 2>&1
grep "pooled levels" "$O/auto.log"; grep "^total" "$O/auto.log"
for r in 1 2; do
  for p in load pass; do
    SUBPIXEL_POOLING=$p timeout 30 /tmp/subpixel bench denoise --width 1920 --height 1080 --precision f32 \
      --frames 30 > "$O/$p$r.log" 2>&1
    echo "$p: $(grep '^total' "$O/$p$r.log")"
  done
done
