#!/usr/bin/env bash
# The one call of the sixteenth session on a lent H100 (15 minutes of device time: one call).
# Run from the repository root there, after tools/gpu_pack.sh here (carry .devpack):
#   bash tools/gpu_runs/2026-11-27-h100/call.sh /tmp/gc && tar -czf $OUT/call.tar.gz -C /tmp gc
# Steps in order of value, each with its own limit, all inside DEADLINE seconds:
# the kernel parity tests on NVIDIA (the Winograd convolution among the candidates), every
# conv3x3 candidate at 1080p in one table (direct, Winograd, tensor cores), the network
# autotuned with the Winograd candidates (the tuning cache keeps every candidate's time per
# layer), with tensor cores, the engine against PyTorch, then a short tools/gpu_train.sh.
set -u
DEADLINE=${DEADLINE:-520}
. tools/gpu_call.sh "${1:?OUT_DIR}"
step test_kernels 90 env SUBPIXEL_COOP_MATRIX=1 "$BIN/kernels" --test-threads 8
step kernels 60 env SUBPIXEL_COOP_MATRIX=1 "$BIN/subpixel" bench kernels --width "$W" --height "$H" --channels 32
step denoise_f32 150 "$BIN/subpixel" bench denoise --width "$W" --height "$H" --precision f32
step coop_denoise 130 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" "$BIN/subpixel" bench denoise \
  --width "$W" --height "$H" --precision auto
step vs_torch 60 env SUBPIXEL_COOP_MATRIX=1 SUBPIXEL_CACHE_DIR="$O/cache-coop" python3 training/bench_vs_torch.py \
  --bin "$BIN/subpixel" --width "$W" --height "$H" --device "${TORCH_DEVICE:-cuda}" --rounds 2 --frames 30
# The GPU campaign path, never run on a GPU before: a small dataset (4 procedural seeds, no
# sparse-light seeds) rendered by 8 shards, then the trainer on CUDA from the shipped weights
# with the shipped model's options, for what time is left.
left=$((DEADLINE - (SECONDS - T0)))
if [ "$left" -gt 120 ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .devpack/.whl/*.whl \
    > "$O/pip.log" 2>&1
  t0=$SECONDS
  PYTHONPATH=/tmp/site SCENES=.devpack/scenes SIZE=${SIZE:-128} TRAIN_SEEDS=4 VAL_SEEDS=2 TRAIN_SPARSE_SEEDS="" \
    VAL_SPARSE_SEEDS="" BACKGROUND=8 TRAIN_SPP=512 JOBS=8 TRAIN_SECONDS=$((left - 100 > 150 ? 150 : left - 100)) \
    TRAIN_ARGS="--thin 0.5 --thin-keep-min 0.02 --lambda ssim=10 --lambda m=0 --background loss --mean-correction loss --lr 1.25e-4" \
    timeout $((left - 10)) tools/gpu_train.sh "$BIN" /tmp/gtw "$O/train" > "$O/gpu_train.log" 2>&1
  echo "== gpu_train: rc $? in $((SECONDS - t0)) s" | tee -a "$O/summary.txt"
  cat /tmp/gtw/render_*.log > "$O/render_shards.log" 2>/dev/null
  rm -f "$O/train/checkpoint.pt"
fi
cat "$O/summary.txt"
