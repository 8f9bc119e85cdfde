#!/usr/bin/env bash
# Prints the first COUNT procedural seeds from START whose scene, with the dataset recipe's
# props, is lit only through its windows: a room enclosure without emitters where at most
# 50 % of the preview camera's hits are directly lit (as `subpixel scene` summarises it).
# Chosen by scene properties alone, before any model sees them. The recipe's sparse-light
# seeds come from it:
#   training/sparse_light_seeds.sh 600000 4   # VAL_SPARSE_SEEDS
#   training/sparse_light_seeds.sh 300000 16  # TRAIN_SPARSE_SEEDS
# Environment: SUBPIXEL (the binary, default target/release/subpixel), SCENES (default
# ../shared/scenes), MAX_LIT (the directly lit percentage, default 50).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
start="${1:?usage: sparse_light_seeds.sh START COUNT}"
count="${2:?usage: sparse_light_seeds.sh START COUNT}"
bin="${SUBPIXEL:-$root/target/release/subpixel}"
scenes="${SCENES:-$root/../shared/scenes}"
max_lit="${MAX_LIT:-50}"
source "$here/recipe_props.sh"
[ -x "$bin" ] || { echo "sparse_light_seeds.sh: no binary at $bin (cargo build --release)" >&2; exit 1; }
found=0
seed="$start"
while [ "$found" -lt "$count" ]; do
  summary="$("$bin" scene --scene "builtin:procedural:$seed" "${props[@]}" 2>&1)"
  lit="$(sed -n 's/.*geometry, [0-9]*% objects, \([0-9]*\)% of hits directly lit.*/\1/p' <<<"$summary")"
  if grep -q "enclosure: room;" <<<"$summary" && grep -q "lights: 0 emissive" <<<"$summary" &&
    [ -n "$lit" ] && [ "$lit" -le "$max_lit" ]; then
    echo "$seed"
    found=$((found + 1))
  fi
  seed=$((seed + 1))
done
