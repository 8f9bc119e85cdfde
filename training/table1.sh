#!/usr/bin/env bash
# Rebuilds the paper's Table 1 layout for our scenes (rows: input, accumulation, RAE, NSRR,
# SSR; columns: scenes; test sequences only) from a dataset rendered by `subpixel dataset`.
#
#   training/table1.sh DATASET PRED [SSR_WEIGHTS] [RAE_WEIGHTS] [NSRR_WEIGHTS]
#
# Runs the PyTorch models (and the non-learned baselines) over DATASET/test with
# `python -m ssr.evaluate`, the WGSL engine's SSR with `subpixel denoise`, then scores
# everything with `subpixel eval --table`. Missing baseline weights are skipped.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
data="$(realpath "$1")"
pred="$(realpath -m "$2")"
ssr="$(realpath "${3:-$root/weights/ssr.safetensors}")"
rae="${4:-}"
nsrr="${5:-}"
py="${PYTHON:-$HOME/.cache/subpixel/venv/bin/python}"
models=(input accumulation)
[ -n "$rae" ] && models+=("rae=$(realpath "$rae")")
[ -n "$nsrr" ] && models+=("nsrr=$(realpath "$nsrr")")
(cd "$here" && "$py" -m ssr.evaluate --data "$data" --split test --out "$pred" --models "${models[@]}" --no-metrics)
cargo build --release --quiet --manifest-path "$root/Cargo.toml"
for seq in "$data"/test/*/; do
  name="$(basename "$seq")"
  "$root/target/release/subpixel" denoise --weights "$ssr" --input "$seq" --out "$pred/ssr/test/$name" >/dev/null
done
"$root/target/release/subpixel" eval --table --pred "$pred" --ref "$data" --split test
