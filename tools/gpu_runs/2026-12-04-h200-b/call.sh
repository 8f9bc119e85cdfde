#!/usr/bin/env bash
# The one call of the forty-first session on a lent H200 (15 minutes of device time).
# Run from the repository root there, after tools/gpu_pack.sh here (carry .devpack):
#   bash tools/gpu_runs/2026-12-04-h200-b/call.sh /tmp/gc; tar -czf $OUT/call.tar.gz -C /tmp gc
# Issue 14: which pass of the output stage is 3.3x its model at 1080p (the fortieth
# session's lease timed the stage as a whole: 1.28 against 0.39 ms), and whether the
# a-trous filter's pixels per invocation (SUBPIXEL_ATROUS_PIXELS, 4 by default, chosen on a
# CPU driver) cost the GPU its occupancy: the network timed with 4, 1, 2, 8 and 4 again,
# tuned from the fortieth lease's cache (same convolution kernels: no tuning). Then the
# new a-trous parity tests on NVIDIA, and issue 10's cpu_twin test whose footprint albedo
# bound failed there (it now names the pixels apart).
# The autotune caches were the fourth lease's, unchanged (in ../2026-12-04-h200/gc).
set -u
DEADLINE=${DEADLINE:-330}
CACHE_FROM=tools/gpu_runs/2026-12-04-h200/gc . tools/gpu_call.sh "${1:?OUT_DIR}"
step test_cpu_twin 40 "$BIN/cpu_twin" --test-threads 16
for px in 4 1 2 8 4; do
  step "denoise_px$px" 60 env SUBPIXEL_ATROUS_PIXELS=$px "$BIN/subpixel" bench denoise \
    --width "$W" --height "$H" --precision f32
  mv "$O/denoise_px$px.log" "$O/denoise_px$px.$SECONDS.log"
done
step test_ssr_api_atrous 60 "$BIN/ssr_api" --test-threads 16 atrous
step coop_denoise 60 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" "$BIN/subpixel" bench denoise \
  --width "$W" --height "$H" --precision auto
echo "== test results" >> "$O/summary.txt"
grep -h "^test result" "$O"/test_*.log >> "$O/summary.txt" 2>/dev/null
grep -h "FAILED\|panicked" -A12 "$O"/test_*.log | head -60 >> "$O/summary.txt" 2>/dev/null
for f in "$O"/denoise_px*.log; do
  echo "== $f" >> "$O/summary.txt"
  grep -E "^output |^total " "$f" | head -30 >> "$O/summary.txt"
done
cat "$O/summary.txt"
