#!/usr/bin/env bash
# Rebuilds the paper's Table 1 layout for our scenes (rows: input, hold-filled, accumulation,
# RAE, NSRR, OIDN (a), OIDN (b) (and both given the footprint albedo when the frames have it,
# OIDN (a) also without the escaped samples when they have the escapes),
# SSR (with the background rows below when the frames have the background buffer), then SSR's
# other and per-scene models; columns: scenes;
# every cell PSNR / SSIM / temporal error; test sequences only) from a dataset rendered by
# `subpixel dataset`.
#
#   training/table1.sh DATASET PRED [SSR_WEIGHTS] [RAE_WEIGHTS] [NSRR_WEIGHTS] [PER_SCENE_DIR]
#
# Defaults: the shipped weights/ssr.safetensors, weights/baselines/{rae,nsrr}.safetensors and,
# for the per-scene row, weights/ssr-SCENE.safetensors for each test scene that has one; every
# other SSR model in the baselines folder (ssr-NAME.safetensors) adds a row named ssr-NAME.
# Runs the PyTorch baselines, the non-learned ones and Intel OIDN (pyoidn, CPU; see
# training/README.md) over DATASET/test with `python -m ssr.evaluate`, the WGSL engine's SSR
# with `subpixel denoise`, then scores everything with `subpixel eval --table`. Missing
# baseline weights are skipped; OIDN (b), which denoises the 1-spp frame `full.RGB`, runs only
# when the dataset's first test frame has those channels. A missing pyoidn is an error.
# SCENES=a,b,... restricts the table to those scene columns, in that order (`procedural` is
# the mean over the procedural scenes), e.g. the held-out scenes:
#   SCENES=living-room,flight-helmet,barn-lamp,procedural training/table1.sh ...
# SSR_ROWS=NAME,... keeps only those of the other SSR models (e.g. SSR_ROWS=ssr-s20-F0;
# SSR_ROWS=none: no other SSR model), for a shorter run.
# PER_FRAME=1 also prints, for each of those scenes (or for all test sequences together
# without SCENES), the table with a column per frame index (`subpixel eval --per-frame`):
# the first frames have no history, the later ones show what the temporal accumulation adds.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
data="$(realpath "$1")"
pred="$(realpath -m "$2")"
ssr="$(realpath "${3:-$root/weights/ssr.safetensors}")"
rae="${4:-$root/weights/baselines/rae.safetensors}"
nsrr="${5:-$root/weights/baselines/nsrr.safetensors}"
per_scene="${6:-$root/weights}"
py="${PYTHON:-$HOME/.cache/subpixel/venv/bin/python}"
models=(input hold accumulation)
[ -f "$rae" ] && models+=("rae=$(realpath "$rae")")
[ -f "$nsrr" ] && models+=("nsrr=$(realpath "$nsrr")")
models+=(oidn-a)
seqs=("$data"/test/*/)
first="${seqs[0]}frame_0000.exr"
has_full=0
if (cd "$here" && "$py" -m ssr.oidn --has-full "$first"); then
  models+=(oidn-b)
  has_full=1
else
  echo "table1.sh: skipping the OIDN (b) row (no 1-spp frame in the dataset)" >&2
fi
# Frames with the footprint albedo (`subpixel dataset --background N`): OIDN given it as its
# albedo image too (oidn-a-footprint, oidn-b-footprint), like for like with an SSR model
# that runs on it (config albedo "footprint", the shipped one).
footprint=0
if (cd "$here" && "$py" -c 'import sys; from ssr.data import exr_size; sys.exit("albedo_footprint.R" not in exr_size(sys.argv[1])[2])' "$first"); then
  footprint=1
  models+=(oidn-a-footprint)
  [ "$has_full" = 1 ] && models+=(oidn-b-footprint)
  # Frames with the samples' escapes too: OIDN (a) fed the frame without its escaped samples
  # and composited with the background, as an SSR model of escaped = "background" is (the
  # fair row against it; ssr/oidn.py).
  if (cd "$here" && "$py" -c 'import sys; from ssr.data import exr_size; sys.exit("escaped.Y" not in exr_size(sys.argv[1])[2])' "$first"); then
    models+=(oidn-a-footprint-escaped)
  fi
fi
(cd "$here" && "$py" -m ssr.evaluate --data "$data" --split test --out "$pred" --models "${models[@]}" --no-metrics)
cargo build --release --quiet --manifest-path "$root/Cargo.toml"
bin="$root/target/release/subpixel"
# denoise WEIGHTS METHOD: the engine's output for sequence $seq as PRED/METHOD/test/$name.
denoise() { "$bin" denoise --weights "$1" --input "$seq" --out "$pred/$2/test/$name" >/dev/null; }
# Frames with the background buffer (`subpixel dataset --background N`): SSR uses it (the
# engine composites it, background + (1 - coverage) x output); more rows show its worth:
# ssr-no-background (the engine ignoring it) and METHOD-background for RAE, NSRR and OIDN (a)
# (their outputs composited the same way: the baselines given the buffer too).
background=0
if (cd "$here" && "$py" -c 'import sys; from ssr.data import exr_size; sys.exit("coverage.Y" not in exr_size(sys.argv[1])[2])' "$first"); then
  background=1
  for m in rae nsrr oidn-a $([ "$footprint" = 1 ] && echo oidn-a-footprint); do
    if [ -d "$pred/$m/test" ]; then
      (cd "$here" && "$py" -m ssr.background_probe --data "$data" --pred "$pred" --write "$m" >/dev/null)
    fi
  done
fi
for seq in "$data"/test/*/; do
  name="$(basename "$seq")"
  denoise "$ssr" ssr
  if [ "$background" = 1 ]; then
    "$bin" denoise --no-background --weights "$ssr" --input "$seq" --out "$pred/ssr-no-background/test/$name" >/dev/null
  fi
  for extra in "$(dirname "$rae")"/ssr-*.safetensors; do
    row="$(basename "$extra" .safetensors)"
    if [ -n "${SSR_ROWS:-}" ] && [[ ",$SSR_ROWS," != *",$row,"* ]]; then continue; fi
    if [ -f "$extra" ]; then denoise "$extra" "$row"; fi
  done
  scene="${name%_test_*}"
  if [ -f "$per_scene/ssr-$scene.safetensors" ]; then
    denoise "$per_scene/ssr-$scene.safetensors" ssr-per-scene
  fi
done
scene_args=()
[ -n "${SCENES:-}" ] && scene_args=(--scenes "$SCENES")
"$bin" eval --table --pred "$pred" --ref "$data" --split test "${scene_args[@]}"
if [ -n "${PER_FRAME:-}" ]; then
  IFS=, read -ra per_frame_scenes <<<"${SCENES:-}"
  [ ${#per_frame_scenes[@]} -gt 0 ] || per_frame_scenes=("")
  for sc in "${per_frame_scenes[@]}"; do
    echo
    echo "Per frame${sc:+, $sc}:"
    "$bin" eval --table --per-frame --pred "$pred" --ref "$data" --split test ${sc:+--scenes "$sc"}
  done
fi
