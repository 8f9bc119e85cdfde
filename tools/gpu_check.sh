#!/usr/bin/env bash
# One call on a lent GPU machine: the GPU-facing tests and every benchmark, in one sitting.
#
#   tools/gpu_check.sh BIN_DIR OUT_DIR
#
# BIN_DIR holds `subpixel` and the test binaries `kernels`, `ssr_api`, `ssr_golden`,
# `render`, `cpu_twin`, `view` built on this machine's architecture
# (`tools/gpu_bins.sh BIN_DIR` copies them out of target/release); OUT_DIR gets one log per
# step, the benchmarks' JSON, the autotuner's cache and a preview of the main job. Each
# step has its own time limit, so one that hangs does not cost the others. The machine
# needs a Vulkan loader and the GPU's ICD; the lent machines of this workplace get the
# loader from `.gl/*.deb` (see README Performance). Steps run in order of value; on an H100
# the whole script takes about 8-10 minutes, so give the call an overall limit that leaves
# time to pack OUT_DIR (logs of the steps not reached are simply missing).
#
# As run on this workplace's lent H100 (the device tool carries `.devpack`, ignored by git):
#   here:   tools/gpu_pack.sh
#   there:  python3 -c "import tarfile; tarfile.open('.devpack/bins.tar.xz').extractall('/tmp/bin')" \
#           && for f in .devpack/.gl/*.deb; do dpkg -x $f /; done; ldconfig; \
#           timeout 540 bash tools/gpu_check.sh /tmp/bin /tmp/gc; tar -czf $OUT/gpu_check.tar.gz -C /tmp gc
set -u
BIN=$(realpath "${1:?BIN_DIR}")
OUT=$(realpath "${2:?OUT_DIR}")
mkdir -p "$OUT"
cd "$(dirname "$0")/.."

. tools/gpu_env.sh "$BIN"
export RUST_LOG=${RUST_LOG:-warn} SUBPIXEL_CACHE_DIR="$OUT/cache"

step() { # name limit_s command...
  local name=$1 limit=$2; shift 2
  local t0=$SECONDS
  timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
  local rc=$?
  echo "== $name: rc $rc in $((SECONDS - t0)) s" | tee -a "$OUT/summary.txt"
}

nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.max.sm,memory.total --format=csv \
  > "$OUT/gpu.txt" 2>&1
cat "$OUT/gpu.txt"

# The first Denoiser::new at a size tunes every layer shape (about 70 s on an H100 at 1080p,
# more with `auto`, which tunes f16 too); later steps at 1080p reuse the cache.
step denoise_f32 200 "$BIN/subpixel" bench denoise --width 1920 --height 1080 --precision f32
# Tensor cores (nn/conv3x3_coop, opt-in, unmeasured before this call): its parity tests, every
# conv candidate with its error against the CPU reference, then the network with them in
# the autotuner's choice (its own cache), f16 activations where faster.
step coop_test 120 env SUBPIXEL_COOP_MATRIX=1 "$BIN/kernels" --test-threads 4 conv3x3
step coop_kernels 90 env SUBPIXEL_COOP_MATRIX=1 "$BIN/subpixel" bench kernels --width 1920 --height 1080 --channels 32
step coop_denoise 240 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$OUT/cache-coop" "$BIN/subpixel" bench denoise \
  --width 1920 --height 1080 --precision auto
# The CPU twin's agreement test (failed on the first H100 call on grazing rays; its tie
# search was widened since): seconds.
step test_cpu_twin 60 "$BIN/cpu_twin" --test-threads 8
step denoise_auto_json 200 "$BIN/subpixel" bench denoise --width 1920 --height 1080 --precision auto --json
step kernels 90 "$BIN/subpixel" bench kernels --width 1920 --height 1080 --channels 32
step frame 90 "$BIN/subpixel" bench frame --sizes 1920x1080
for t in kernels ssr_api ssr_golden; do
  step "test_$t" 120 "$BIN/$t" --test-threads 4
done
step vs_torch 120 python3 training/bench_vs_torch.py --bin "$BIN/subpixel" --width 1920 --height 1080 \
  --device cuda --rounds 3 --frames 50
step run 120 "$BIN/subpixel" run --width 1920 --height 1080 --out "$OUT/run"
# Keep what comes back small: one preview, the rest removed.
if [ -d "$OUT/run" ]; then
  last=$(ls "$OUT/run"/*.png 2>/dev/null | tail -1)
  [ -n "$last" ] && cp "$last" "$OUT/run_last_frame.png"
  rm -rf "$OUT/run"
fi
step render 90 "$BIN/subpixel" bench render --width 1920 --height 1080
step denoise_f16 60 "$BIN/subpixel" bench denoise --width 1920 --height 1080 --precision f16
step torch_modes 120 python3 training/bench_torch.py --weights weights/ssr.safetensors --width 1920 \
  --height 1080 --device cuda --frames 50
for t in render view; do
  step "test_$t" 120 "$BIN/$t" --test-threads 8
done
echo "== test results"
grep -h "^test result" "$OUT"/test_*.log
grep -h "FAILED\|panicked" "$OUT"/test_*.log | head -20
cat "$OUT/summary.txt"
