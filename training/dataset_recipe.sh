#!/usr/bin/env bash
# The generic dataset (issues 10 and 11): many distinct scenes at 128x128 with clean
# references, rendered by the CPU twin on a machine without a GPU, resumable and sharded.
#
#   training/dataset_recipe.sh OUT [PHASE ...]
#
# PHASES (default: all, in this order, so that a partial run is already useful):
#   heldout  test split of the held-out scenes (living-room, flight-helmet, barn-lamp:
#            2 sequences each) and of 20 procedural test seeds (1 sequence each)
#   val      validation split: the 6 training scenes, 10 procedural validation seeds and
#            the sparse-light validation seeds (VAL_SPARSE_SEEDS)
#   train    training split, round-robin (one more sequence of every scene per round):
#            6 fixed scenes x 5 sequences + 60 procedural seeds x 2 sequences = 150
#            sequences of 8 frames = 1,200 frames over 66 scenes, then the sparse-light
#            training seeds (TRAIN_SPARSE_SEEDS, 1 sequence each: 16 more sequences)
#   test     test split of the 6 training scenes (1 sequence each)
#   block    one block of a rolling training run (training/registered.sh F12, F13): with
#            BLOCK=K, the 6 fixed scenes' train sequence K mod 5, the 4 sparse-light train
#            seeds of group K mod 4 (TRAIN_SPARSE_SEEDS, 4 at a time) and the first
#            sequences of the BLOCK_SEEDS (default 20) procedural train seeds from
#            BLOCK_FIRST + K x BLOCK_SEEDS (BLOCK_FIRST default 280): every block brings
#            new procedural scenes (about 35 minutes of both cores on a 2-core machine)
#
# Held-out scenes never enter train or val, neither as scenes nor as props. Procedural
# seeds of the three splits are disjoint ranges; every sequence of every split flies its
# own camera path (seeded by scene, split and number).
#
# Environment: SUBPIXEL (the binary; default target/dist/subpixel, which the recipe builds
# with `cargo build --profile dist`: whole-program optimisation, the same images as a
# release build, faster), SCENES (default
# ../shared/scenes), SPP (reference samples, default 1024), TRAIN_SPP (reference samples of
# the val and train phases, default SPP), SIZE (default 128), HELDOUT_SEQUENCES (per
# held-out scene, default 2), TEST_SEEDS (procedural test seeds, default 20), TRAIN_SEEDS
# (procedural train seeds, default 60, SEED_SEQUENCES sequences each: default 2, at most 5;
# 1 renders every seed's first sequence and stops there), VAL_SEEDS (default 10),
# VAL_SPARSE_SEEDS (default "600320 600788 601084 601268": rooms lit only through their
# windows, the kind of light that trips the generic model on living-room; chosen by scene
# properties alone, before any model saw them: the first four seeds from 600000 whose
# scene, with the props below, is a room enclosure without emitters where at most 50 % of
# the preview camera's hits are directly lit, per `subpixel scene`; "" for none;
# `training/sparse_light_seeds.sh 600000 4` prints them), TRAIN_SPARSE_SEEDS (default: the
# first 16 such seeds from 300000, `training/sparse_light_seeds.sh 300000 16`; one sequence
# each, rendered after the rest of the train phase; "" for none),
# BACKEND (the renderer, `subpixel dataset --backend`: cpu, the default, or gpu on a machine
# with a real GPU, where several SHARDs side by side keep it busy), BACKGROUND=N (also store each frame's directly seen environment from N x N lookups per
# pixel, `subpixel dataset --background`; re-running the recipe with it adds the channels to
# the frames already rendered), FRAMES (default 8), SHARD=K/N (this machine renders the sequences whose hash is K mod N;
# run the same command with 0/N .. N-1/N on N machines and merge the OUT folders), PROCEDURAL=0 (skip procedural
# scenes, e.g. before they exist), NOISE_TARGET=DB (each reference doubles its samples until
# the PSNR between its halves reaches DB, `subpixel dataset --reference-noise-target`; up to
# SPP_MAX, default 16 x its base count: about 12x the samples on average for 40 dB on val,
# training/README.md, so meant for a GPU), ONLY_EXISTING=1 (visit only the sequences already
# complete in OUT, rendering nothing new: with BACKGROUND, adds the channels frames written
# before lack, e.g. the samples' `escaped`), ONLY_LIST=1 (print the folder of each sequence
# the phases hold, SPLIT/NAME a line, rendering nothing: what a training root of them
# links). Finished frames are skipped, so re-running continues;
# each frame is written atomically. A build for the machine's own CPU renders 5-8 % faster
# still (CARGO_TARGET_DIR=~/work-data/target-native RUSTFLAGS="-C target-cpu=native" cargo
# build --profile dist, then SUBPIXEL=~/work-data/target-native/dist/subpixel), but its
# images differ from the default build's in the last bits (fused multiply-adds where the
# CPU has them), so frames rendered by the two differ in noise: keep one per dataset.
# To stop a background run cleanly, `touch OUT/STOP`: it stops before its next sequence
# (a killed run leaves at most one unfinished sequence, which the next run completes).
# Logs go to stdout: run it with nohup, e.g.
#   nohup training/dataset_recipe.sh ~/work-data/ds > ~/work-data/ds.log 2>&1 &
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
out="${1:?usage: dataset_recipe.sh OUT [heldout|val|train|test|block ...]}"
shift
phases=("$@")
[ ${#phases[@]} -eq 0 ] && phases=(heldout val train test)
only_list="${ONLY_LIST:-0}"
if [ -z "${SUBPIXEL:-}" ] && [ "$only_list" != 1 ]; then
  (cd "$root" && cargo build --profile dist --bin subpixel --quiet)
fi
bin="${SUBPIXEL:-$root/target/dist/subpixel}"
scenes="${SCENES:-$root/../shared/scenes}"
spp="${SPP:-1024}"
train_spp="${TRAIN_SPP:-$spp}"
heldout_sequences="${HELDOUT_SEQUENCES:-2}"
test_seeds="${TEST_SEEDS:-20}"
train_seeds="${TRAIN_SEEDS:-60}"
val_seeds="${VAL_SEEDS:-10}"
val_sparse_seeds="${VAL_SPARSE_SEEDS-600320 600788 601084 601268}"
train_sparse_seeds="${TRAIN_SPARSE_SEEDS-300656 301436 301556 301680 302052 302752 302792 303224 303724 303764 303776 304304 304328 305064 305240 305480}"
size="${SIZE:-128}"
frames="${FRAMES:-8}"
shard="${SHARD:-0/1}"
shard_k="${shard%/*}"
shard_n="${shard#*/}"
procedural="${PROCEDURAL:-1}"
seed_sequences="${SEED_SEQUENCES:-2}"
block="${BLOCK:-}"
block_seeds="${BLOCK_SEEDS:-20}"
block_first="${BLOCK_FIRST:-280}"
[[ "$seed_sequences" =~ ^[0-5]$ ]] || { echo "SEED_SEQUENCES must be 0-5, got '$seed_sequences'" >&2; exit 2; }
[ -x "$bin" ] || [ "$only_list" = 1 ] || { echo "no binary at $bin (SUBPIXEL)" >&2; exit 1; }

fixed=(builtin:cornell builtin:room "$scenes/cbox" "$scenes/cornell-box" "$scenes/dining-room" "$scenes/staircase2")
held_out=("$scenes/living-room" "$scenes/flight-helmet" "$scenes/barn-lamp")
# Props for procedural scenes (recipe_props.sh): nothing of a held-out scene.
source "$here/recipe_props.sh"

# render SPP SCENE SPLIT K [EXTRA...]: sequence K of SCENE's SPLIT with SPP-sample
# references, when it is this shard's (a stable hash of scene, split and K picks the shard).
render() {
  local rspp="$1" scene="$2" split="$3" k="$4"
  shift 4
  local h
  h=$(printf '%s %s %s' "$scene" "$split" "$k" | cksum | cut -d' ' -f1)
  if [ $((h % shard_n)) -ne "$shard_k" ]; then
    return 0
  fi
  if [ "$only_list" = 1 ]; then
    local name_
    name_="$(basename "${scene#builtin:}")"
    echo "$split/${name_//:/_}_${split}_$(printf '%03d' "$k")"
    return 0
  fi
  if [ "${ONLY_EXISTING:-0}" = 1 ]; then
    local name dir
    name="$(basename "${scene#builtin:}")"
    dir="$out/$split/${name//:/_}_${split}_$(printf '%03d' "$k")"
    [ -f "$dir/sequence.json" ] && [ -f "$dir/$(printf 'frame_%04d.exr' $((frames - 1)))" ] || return 0
  fi
  if [ -e "$out/STOP" ]; then
    echo "== $(date -u +%FT%TZ) $out/STOP exists: stopping before $split $scene sequence $k"
    exit 0
  fi
  echo "== $(date -u +%FT%TZ) $split $scene sequence $k"
  "$bin" dataset --scene "$scene" --split "$split" --first-sequence "$k" --sequences "$((k + 1))" \
    --frames "$frames" --width "$size" --height "$size" --reference-spp "$rspp" --backend "${BACKEND:-cpu}" \
    ${BACKGROUND:+--background "$BACKGROUND"} \
    ${NOISE_TARGET:+--reference-noise-target "$NOISE_TARGET"} ${SPP_MAX:+--reference-spp-max "$SPP_MAX"} \
    --out "$out" "$@"
}
proc() { echo "builtin:procedural:$1"; }

for phase in "${phases[@]}"; do
  case "$phase" in
    heldout)
      for k in $(seq 0 $((heldout_sequences - 1))); do
        for s in "${held_out[@]}"; do render "$spp" "$s" test "$k"; done
      done
      if [ "$procedural" = 1 ] && [ "$test_seeds" -gt 0 ]; then
        for seed in $(seq 1000000 $((1000000 + test_seeds - 1))); do
          render "$spp" "$(proc "$seed")" test 0 "${props[@]}"
        done
      fi
      ;;
    val)
      for s in "${fixed[@]}"; do render "$train_spp" "$s" val 0; done
      if [ "$procedural" = 1 ] && [ "$val_seeds" -gt 0 ]; then
        for seed in $(seq 500000 $((500000 + val_seeds - 1))); do
          render "$train_spp" "$(proc "$seed")" val 0 "${props[@]}"
        done
        for seed in $val_sparse_seeds; do
          render "$train_spp" "$(proc "$seed")" val 0 "${props[@]}"
        done
      fi
      ;;
    train)
      for k in 0 1 2 3 4; do
        for s in "${fixed[@]}"; do render "$train_spp" "$s" train "$k"; done
        if [ "$procedural" = 1 ] && [ "$k" -lt "$seed_sequences" ] && [ "$train_seeds" -gt 0 ]; then
          for seed in $(seq 0 $((train_seeds - 1))); do
            render "$train_spp" "$(proc "$seed")" train "$k" "${props[@]}"
          done
        fi
      done
      if [ "$procedural" = 1 ]; then
        for seed in $train_sparse_seeds; do
          render "$train_spp" "$(proc "$seed")" train 0 "${props[@]}"
        done
      fi
      ;;
    test)
      for s in "${fixed[@]}"; do render "$spp" "$s" test 0; done
      ;;
    block)
      [[ "$block" =~ ^[0-9]+$ ]] || { echo "phase block needs BLOCK=K (a block number), got '$block'" >&2; exit 2; }
      [[ "$block_seeds" =~ ^[1-9][0-9]*$ ]] && [[ "$block_first" =~ ^[0-9]+$ ]] ||
        { echo "BLOCK_SEEDS must be a positive integer and BLOCK_FIRST a seed, got '$block_seeds', '$block_first'" >&2; exit 2; }
      first=$((block_first + block * block_seeds))
      last=$((first + block_seeds - 1))
      # Procedural train seeds stay below the sparse-light range (300000) and the val and
      # test ranges above it.
      [ "$last" -lt 300000 ] || { echo "block $block: seeds $first-$last reach the sparse-light range (300000)" >&2; exit 2; }
      for s in "${fixed[@]}"; do render "$train_spp" "$s" train $((block % 5)); done
      if [ "$procedural" = 1 ]; then
        read -r -a sparse <<< "$train_sparse_seeds"
        group=$((block % 4))
        for seed in "${sparse[@]:$((4 * group)):4}"; do
          render "$train_spp" "$(proc "$seed")" train 0 "${props[@]}"
        done
        for seed in $(seq "$first" "$last"); do
          render "$train_spp" "$(proc "$seed")" train 0 "${props[@]}"
        done
      fi
      ;;
    *)
      echo "unknown phase '$phase' (heldout, val, train, test, block)" >&2
      exit 2
      ;;
  esac
done
[ "$only_list" = 1 ] || echo "== $(date -u +%FT%TZ) done: $out"
