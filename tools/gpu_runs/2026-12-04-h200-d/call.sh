#!/usr/bin/env bash
# The forty-first session's third call on a lent H200. Run from the repository root there,
# after tools/gpu_pack.sh here, with the previous build's `subpixel` (commit f35890c)
# stripped and xz-compressed as .devpack/before/subpixel.xz (carry .devpack):
#   bash tools/gpu_runs/2026-12-04-h200-d/call.sh /tmp/gc; tar -czf $OUT/call.tar.gz -C /tmp gc
# The a-trous filter with one division per tap (the depth term's divisors multiplied)
# against f35890c's two, alternated, at 2 and 4 pixels per invocation; what auto picks;
# cpu_twin with seam and silhouette rays explained; the a-trous parity tests.
# Not run yet: the forty-first session's third call got no machine ("no new device
# machine is lent at present"). For the next lease: build f35890c's `subpixel` for
# .devpack/before (git worktree), then this build's pack.
set -u
DEADLINE=${DEADLINE:-240}
CACHE_FROM=tools/gpu_runs/2026-12-04-h200/gc . tools/gpu_call.sh "${1:?OUT_DIR}"
mkdir -p /tmp/before
python3 -c "import lzma, shutil; shutil.copyfileobj(lzma.open('.devpack/before/subpixel.xz'), open('/tmp/before/subpixel', 'wb'))"
chmod +x /tmp/before/subpixel
step test_cpu_twin 40 "$BIN/cpu_twin" --test-threads 16
step test_ssr_api_atrous 60 "$BIN/ssr_api" --test-threads 16 atrous
for round in 1 2; do
  for px in 2 4; do
    for b in before after; do
      exe="$BIN/subpixel"; [ "$b" = before ] && exe=/tmp/before/subpixel
      step "denoise_${b}_px${px}_$round" 30 env SUBPIXEL_ATROUS_PIXELS=$px "$exe" bench denoise \
        --width "$W" --height "$H" --precision f32
    done
  done
done
step denoise_auto 30 env RUST_LOG=info "$BIN/subpixel" bench denoise --width "$W" --height "$H" --precision f32
echo "== test results" >> "$O/summary.txt"
grep -h "^test result" "$O"/test_*.log >> "$O/summary.txt" 2>/dev/null
grep -h "footprint albedo close\|FAILED\|panicked" "$O"/test_*.log | head -20 >> "$O/summary.txt" 2>/dev/null
for f in "$O"/denoise_*.log; do
  echo "== $f" >> "$O/summary.txt"
  grep -E "a-trous filter|^output  mean atrous|^output  +0|^total " "$f" | head -8 >> "$O/summary.txt"
done
cat "$O/summary.txt"
