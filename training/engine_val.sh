#!/usr/bin/env bash
# Engine validation of SSR weights files, the score the training rounds' pre-registered rules
# choose by (weights/README.md): the WGSL engine (`subpixel denoise`, with the background and
# the mean correction as shipped) over every val sequence of DATASET, scored by `subpixel
# eval --table --split val`, whose `mean` column (the mean over the scene columns, the
# procedural scenes one column) holds the PSNR and SSIM the rules compare. (The engine-val
# brightness figures in weights/README are the mean of the `--json` cells' `brightness`,
# |ln(P/R)|, times 100; the table prints exp of the mean minus 1.)
#
#   training/engine_val.sh DATASET PRED [NAME=]WEIGHTS [[NAME=]WEIGHTS ...]
#
# Each model's output goes to PRED/NAME/val (NAME defaults to the file's name without
# .safetensors); sequences already denoised there are kept, so an interrupted run continues
# and a second call adds rows. EXTRA=DIR,... adds rows already in other folders (e.g. OIDN's
# val output from `python -m ssr.evaluate --split val --out DIR`: its method folders are
# linked into PRED). PER_FRAME=1 also prints the table with a column per frame index.
# SPLIT=train (or test) scores another split the same way (default val), e.g. a root of links
# to training sequences for how a model does on scenes it was trained on (training/README,
# Generalisation 21); the rules only ever read val.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
usage="usage: engine_val.sh DATASET PRED [NAME=]WEIGHTS [...]"
data="$(realpath "${1:?$usage}")"
pred="$(realpath -m "${2:?$usage}")"
shift 2
[ $# -gt 0 ] || { echo "engine_val.sh: name at least one weights file ($usage)" >&2; exit 2; }
split="${SPLIT:-val}"
[ -d "$data/$split" ] || { echo "engine_val.sh: $data/$split: no such folder (a dataset with a $split split)" >&2; exit 2; }
bin="${SUBPIXEL:-$root/target/release/subpixel}"
if [ -z "${SUBPIXEL:-}" ]; then
  cargo build --release --quiet --manifest-path "$root/Cargo.toml"
fi
mkdir -p "$pred"
for arg in "$@"; do
  if [[ "$arg" == *=* ]]; then name="${arg%%=*}"; weights="${arg#*=}"; else
    weights="$arg"; name="$(basename "$arg" .safetensors)"; fi
  [ -f "$weights" ] || { echo "engine_val.sh: $weights: no such weights file" >&2; exit 2; }
  for seq in "$data/$split"/*/; do
    [ -f "$seq/sequence.json" ] || continue
    out="$pred/$name/$split/$(basename "$seq")"
    n_ref=$(find "$seq" -maxdepth 1 -name 'frame_*.exr' | wc -l)
    if [ -d "$out" ] && [ "$(find "$out" -maxdepth 1 -name 'frame_*.exr' | wc -l)" = "$n_ref" ]; then
      continue
    fi
    # (`subpixel denoise` writes each frame atomically: an interrupted sequence has fewer
    # frames than its input and is denoised again here)
    "$bin" denoise --weights "$weights" --input "$seq" --out "$out" >/dev/null
  done
done
if [ -n "${EXTRA:-}" ]; then
  IFS=, read -ra extra <<<"$EXTRA"
  for dir in "${extra[@]}"; do
    for m in "$dir"/*/; do
      [ -d "$m/$split" ] && [ ! -e "$pred/$(basename "$m")" ] && ln -s "$(realpath "$m")" "$pred/$(basename "$m")"
    done
  done
fi
"$bin" eval --table --pred "$pred" --ref "$data" --split "$split"
if [ -n "${PER_FRAME:-}" ]; then
  echo
  echo "Per frame:"
  "$bin" eval --table --per-frame --pred "$pred" --ref "$data" --split "$split"
fi
