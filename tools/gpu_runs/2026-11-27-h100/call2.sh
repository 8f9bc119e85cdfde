#!/usr/bin/env bash
# Second call of the sixteenth session: the autotuner with the spin-up and the interleaved
# re-timing, two tunings from fresh caches back to back (f32, 1080p), to compare their
# choices and times. Carry .devpack (with new/subpixel.xz, this build).
set -u
O=${1:?OUT}; mkdir -p "$O"
for f in .devpack/.gl/*.deb; do dpkg -x "$f" /; done; ldconfig
xz -dc .devpack/new/subpixel.xz > /tmp/subpixel && chmod +x /tmp/subpixel
. tools/gpu_env.sh
export RUST_LOG=warn
for k in 1 2; do
  t0=$SECONDS
  SUBPIXEL_CACHE_DIR="$O/cache$k" timeout 75 /tmp/subpixel bench denoise --width 1920 --height 1080 \
    --precision f32 --frames 30 > "$O/denoise$k.log" 2>&1
  echo "== tuning $k: rc $? in $((SECONDS - t0)) s"
  grep "^total" "$O/denoise$k.log"
done
