#!/usr/bin/env bash
# The one call of the fortieth session on a lent H200 (15 minutes of device time: one call).
# Run from the repository root there, after tools/gpu_pack.sh here (carry .devpack):
#   bash tools/gpu_runs/2026-12-04-h200/call.sh /tmp/gc; tar -czf $OUT/call.tar.gz -C /tmp gc
# Today's figures for issue 14 (the kernels and the network as they stand since the third
# lease: texture-reading tilings, f16 weights, shared textures, the pooling choice, the
# output pass with its edge-aware mean correction), and the GPU-facing tests, in order of
# value, each with its own limit, all inside DEADLINE seconds.
# As run on a fresh H200: test_kernels, coop_denoise, test_ssr_golden and test_ssr_api hit
# their limits (the drivers' first pipeline compiles); three follow-up calls on the warm
# machine ran the tests with --test-threads 16 (all passed within 41 s each) and the tensor-core
# tuning to its end (gc/*.call2-4.log).
set -u
DEADLINE=${DEADLINE:-500}
. tools/gpu_call.sh "${1:?OUT_DIR}"
# Parity first (it also brings the GPU up from idle clocks before anything is timed).
step test_kernels 90 env SUBPIXEL_COOP_MATRIX=1 "$BIN/kernels" --test-threads 8
step denoise_f32 150 "$BIN/subpixel" bench denoise --width "$W" --height "$H" --precision f32
step coop_denoise 120 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" "$BIN/subpixel" bench denoise \
  --width "$W" --height "$H" --precision auto
step vs_torch 60 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" python3 training/bench_vs_torch.py \
  --bin "$BIN/subpixel" --width "$W" --height "$H" --device cuda --rounds 2 --frames 30
step test_ssr_golden 40 "$BIN/ssr_golden" --test-threads 8
step test_ssr_api 40 "$BIN/ssr_api" --test-threads 8
step render 60 "$BIN/subpixel" bench render --width "$W" --height "$H"
step test_cpu_twin 60 "$BIN/cpu_twin" --test-threads 16
step frame 60 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" "$BIN/subpixel" bench frame --sizes "${W}x${H}"
echo "== test results" >> "$O/summary.txt"
grep -h "^test result" "$O"/test_*.log >> "$O/summary.txt" 2>/dev/null
grep -h "FAILED\|panicked" "$O"/test_*.log | head -20 >> "$O/summary.txt" 2>/dev/null
cat "$O/summary.txt"
