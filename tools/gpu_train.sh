#!/usr/bin/env bash
# The generic model's campaign on a lent GPU machine, one call at a time: renders the
# dataset's val and train splits with the WGSL tracer (JOBS shards of
# training/dataset_recipe.sh side by side, so small frames keep the GPU busy), then trains
# SSR on them with PyTorch on CUDA for TRAIN_SECONDS, resuming from CHECKPOINT when given.
# The renderer is deterministic, so every call renders the same dataset and a run continues
# across calls (and sessions) from the checkpoint that comes back in OUT. Held-out scenes
# are neither rendered nor read here: score the weights on this machine's held-out split
# (training/campaign.sh heldout, table).
#
#   tools/gpu_train.sh BIN_DIR WORK OUT
#
# BIN_DIR holds `subpixel` (tools/gpu_bins.sh). WORK is scratch space (the dataset, the
# run). OUT gets: checkpoint.pt (the run's state: carry it into the next call as
# CHECKPOINT), log.jsonl and run.json (losses, validation on the val split), the newest
# snapshot and, once the run reaches ITERS, weights.safetensors with full provenance;
# render.log and train.log.
#
# Environment: SCENES (the shared scenes: the fixed training scenes and the props of the
# procedural ones; default ../shared/scenes), JOBS (default 8), RENDER_BACKEND (default
# gpu), SIZE (default 128), TRAIN_SPP (default 512), VAL_SEEDS (default 6) and the
# recipe's other variables (NOISE_TARGET=40: references to 40 dB between halves, about 12x
# the samples, some 30 minutes of H100 for the whole recipe by the measured path rate:
# a call of its own, not measured yet; without it, 8 shards render about 2.3 frames/s on an
# H100, training/README.md); TRAIN_SECONDS (default 300), ITERS (default 20000: the run's
# length, which sets its learning-rate schedule), DEVICE (default cuda), CHECKPOINT, INIT
# (weights to start a new run from; default weights/ssr.safetensors), TRAIN_ARGS (default
# "--thin 0.5 --thin-keep-min 0.02 --lambda ssim=10", the shipped model's), PYTHON (default python3).
#
# As a call on this workplace's lent GPU machine (after tools/gpu_pack.sh here; carry .devpack):
#   python3 -c "import tarfile; tarfile.open('.devpack/bins.tar.xz').extractall('/tmp/bin')" \
#   && for f in .devpack/.gl/*.deb; do dpkg -x $f /; done; ldconfig \
#   && python3 -m pip install -q --no-index --no-deps --target /tmp/site .devpack/.whl/*.whl \
#   && PYTHONPATH=/tmp/site SCENES=.devpack/scenes TRAIN_SECONDS=360 [CHECKPOINT=.devpack/checkpoint.pt] \
#      tools/gpu_train.sh /tmp/bin /tmp/work $OUT
set -euo pipefail
bin_dir=$(realpath "${1:?usage: gpu_train.sh BIN_DIR WORK OUT}")
work=$(realpath -m "${2:?WORK}")
out=$(realpath -m "${3:?OUT}")
cd "$(dirname "$0")/.."
root=$PWD
mkdir -p "$work" "$out"
py="${PYTHON:-python3}"
jobs="${JOBS:-8}"
ds="$work/ds"
run="$work/runs/ssr"
. tools/gpu_env.sh "$bin_dir"

t0=$SECONDS
echo "== rendering val and train with $jobs shards side by side"
pids=()
for k in $(seq 0 $((jobs - 1))); do
  SHARD="$k/$jobs" BACKEND="${RENDER_BACKEND:-gpu}" SUBPIXEL="$bin_dir/subpixel" \
    SCENES="$(realpath "${SCENES:-$root/../shared/scenes}")" SIZE="${SIZE:-128}" \
    TRAIN_SPP="${TRAIN_SPP:-512}" VAL_SEEDS="${VAL_SEEDS:-6}" \
    training/dataset_recipe.sh "$ds" val train > "$work/render_$k.log" 2>&1 &
  pids+=($!)
done
failed=0
for p in "${pids[@]}"; do wait "$p" || failed=1; done
cat "$work"/render_*.log > "$out/render.log"
[ "$failed" = 0 ] || { echo "a render shard failed: see $out/render.log" >&2; exit 1; }
echo "== rendered $(find "$ds" -name 'frame_*.exr' | wc -l) frames in $((SECONDS - t0)) s"

mkdir -p "$run"
resume=()
init=()
if [ -n "${CHECKPOINT:-}" ]; then
  cp "$CHECKPOINT" "$run/checkpoint.pt"
  resume=(--resume)
fi
# A resumed run names the same starting weights (the trainer checks them).
if [ "${INIT:-}" != none ]; then
  init=(--init "$(realpath "${INIT:-$root/weights/ssr.safetensors}")")
fi
t1=$SECONDS
echo "== training for at most ${TRAIN_SECONDS:-300} s"
# SIGTERM at the time limit: the trainer finishes its iteration, checkpoints and exits.
set +e
(cd training && timeout -s TERM "${TRAIN_SECONDS:-300}" "$py" -m ssr.train --data "$ds" --out "$run" \
  --device "${DEVICE:-cuda}" --iters "${ITERS:-20000}" --batch 8 --crop 128 --lr 5e-4 --workers 4 \
  --cache memory --val-every 1000 --val-frames 8 --log-every 100 --ckpt-every 500 \
  --snapshot-every 1000 "${init[@]}" "${resume[@]}" ${TRAIN_ARGS:---thin 0.5 --thin-keep-min 0.02 --lambda ssim=10}) \
  > "$out/train.log" 2>&1
rc=$?
set -e
echo "== trainer rc $rc after $((SECONDS - t1)) s (124: stopped at the time limit)"
tail -n 3 "$out/train.log"
for f in checkpoint.pt log.jsonl run.json weights.safetensors; do
  [ -f "$run/$f" ] && cp "$run/$f" "$out/"
done
last=$(ls "$run"/snapshots/*.safetensors 2>/dev/null | tail -n 1 || true)
[ -n "$last" ] && cp "$last" "$out/"
ls -la "$out"
