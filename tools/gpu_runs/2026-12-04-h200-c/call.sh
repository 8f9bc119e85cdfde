#!/usr/bin/env bash
# The forty-first session's second call on a lent H200, after the first
# (tools/gpu_runs/2026-12-04-h200-b: the a-trous levels were 0.20-0.30 ms each at 1080p
# against 0.05 modelled, with rows of 2 pixels per invocation the fastest, 1.16 ms for the
# output stage against 1.28 with 4). Run from the repository root there, after
# tools/gpu_pack.sh here (carry .devpack):
#   bash tools/gpu_runs/2026-12-04-h200-c/call.sh /tmp/gc; tar -czf $OUT/call.tar.gz -C /tmp gc
# The workgroup-tiled a-trous kernel (ssr/mean_atrous_tiles) against rows of 4, twice
# each, and what SUBPIXEL_ATROUS=auto chooses (its timings in the log); its parity on
# NVIDIA; and cpu_twin with the footprint albedo's seam rays told apart.
# After this call the tiled kernel (slower on the H200 and on the CPU driver) was removed,
# and with it SUBPIXEL_ATROUS: the choice is SUBPIXEL_ATROUS_PIXELS (auto, or 1 to 8).
# The autotune caches were the fourth lease's, unchanged (in ../2026-12-04-h200/gc).
set -u
DEADLINE=${DEADLINE:-240}
CACHE_FROM=tools/gpu_runs/2026-12-04-h200/gc . tools/gpu_call.sh "${1:?OUT_DIR}"
step test_ssr_api_atrous 60 "$BIN/ssr_api" --test-threads 16 atrous
step test_cpu_twin 40 "$BIN/cpu_twin" --test-threads 16
for a in auto tiles rows4 tiles rows4; do
  step "denoise_$a" 40 env RUST_LOG=info SUBPIXEL_ATROUS=$a "$BIN/subpixel" bench denoise \
    --width "$W" --height "$H" --precision f32
  mv "$O/denoise_$a.log" "$O/denoise_$a.$SECONDS.log"
done
step coop_denoise 40 env RUST_LOG=info SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" \
  "$BIN/subpixel" bench denoise --width "$W" --height "$H" --precision auto
echo "== test results" >> "$O/summary.txt"
grep -h "^test result" "$O"/test_*.log >> "$O/summary.txt" 2>/dev/null
grep -h "footprint albedo close\|FAILED\|panicked" "$O"/test_*.log | head -20 >> "$O/summary.txt" 2>/dev/null
for f in "$O"/denoise_*.log "$O"/coop_denoise.log; do
  echo "== $f" >> "$O/summary.txt"
  grep -E "a-trous filter|^output  (mean|store)|^output  +0|^total " "$f" | head -12 >> "$O/summary.txt"
done
cat "$O/summary.txt"
