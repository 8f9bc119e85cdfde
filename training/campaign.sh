#!/usr/bin/env bash
# One session of the generic-model campaign (issue 11) on a machine without a GPU: data,
# training, learning curve and the held-out table, each phase resumable.
#
#   training/campaign.sh WORK PHASE [PHASE ...]
#
# WORK is a folder outside the repository (e.g. ~/work-data): the dataset goes to WORK/ds,
# runs to WORK/runs, predictions to WORK/pred. Phases:
#   data     the val and train splits (dataset_recipe.sh phases val, train) with TRAIN_SPP
#            (default 512) references, on every core. It runs until done or until
#            `touch WORK/ds/STOP`, which ends it before the next sequence.
#   heldout  the held-out test split (dataset_recipe.sh phase heldout) with SPP (default 1024)
#            references: HELDOUT_SEQUENCES (default 1) sequences of living-room,
#            flight-helmet and barn-lamp and TEST_SEEDS (default 20) procedural test seeds.
#   train    SSR (the default version-2 config) on WORK/ds into WORK/runs/RUN (default
#            ssr): ITERS (default 7000) iterations, batch 8, 64x64 crops, lr 5e-4,
#            snapshots every 500 iterations. When weights/ssr.safetensors is already a
#            version-2 model (an earlier session's), training starts from it (--init), so
#            sessions continue one campaign; INIT=none starts from scratch. Resumes from
#            WORK/runs/RUN/checkpoint.pt when there is one. TRAIN_ARGS gives the ssr.train
#            options of the recipe (default the shipped model's: "--thin 0.5
#            --thin-keep-min 0.02 --lambda ssim=10"; replace it whole to change one).
#   curve    weights/ssr-training.png and .json: training loss and held-out PSNR against
#            iterations (ssr.curve; reporting only, no selection), earlier sessions' points
#            (the committed JSON) in front.
#   table    the held-out table: training/table1.sh over WORK/ds with the held-out columns
#            (SCENES, default living-room,flight-helmet,barn-lamp,procedural), the engine
#            scoring every SSR weights file as in table1.sh; then each column per frame
#            index (PER_FRAME=1 by default; PER_FRAME= leaves it out).
# DS (default WORK/ds) names another dataset root for every phase, e.g. a folder whose
# train split links a subset of WORK/ds/train (an A/B arm without some sequences).
# THREADS (default: all) limits the CPU threads of the renderer (RAYON_NUM_THREADS) and of
# PyTorch, e.g. THREADS=1 for `heldout` and `train` side by side on 2 cores:
#   THREADS=1 nohup training/campaign.sh ~/work-data heldout > ~/work-data/heldout.log 2>&1 &
#   THREADS=1 nohup training/campaign.sh ~/work-data train > ~/work-data/train.log 2>&1 &
# DRY_RUN=1 makes `train` print its ssr.train arguments, one a line, instead of running it
# (tests/test_registered.py checks the registered runs' commands that way).
# Held-out scenes never enter training or model selection: the trainer validates on the val
# split only, and the curve's held-out scores are written for the plot, never read back.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
work="$(realpath -m "${1:?usage: campaign.sh WORK data|heldout|train|curve|table ...}")"
shift
[ $# -gt 0 ] || { echo "campaign.sh: name at least one phase (data, heldout, train, curve, table)" >&2; exit 2; }
py="${PYTHON:-$HOME/.cache/subpixel/venv/bin/python}"
run="${RUN:-ssr}"
threads="${THREADS:-0}"
if [ "$threads" != 0 ]; then export RAYON_NUM_THREADS="$threads" OMP_NUM_THREADS="$threads"; fi
mkdir -p "$work"
ds="$(realpath -m "${DS:-$work/ds}")"

for phase in "$@"; do
  case "$phase" in
    data)
      SPP="${SPP:-1024}" TRAIN_SPP="${TRAIN_SPP:-512}" VAL_SEEDS="${VAL_SEEDS:-6}" \
        "$here/dataset_recipe.sh" "$ds" val train
      ;;
    heldout)
      SPP="${SPP:-1024}" HELDOUT_SEQUENCES="${HELDOUT_SEQUENCES:-1}" TEST_SEEDS="${TEST_SEEDS:-20}" \
        "$here/dataset_recipe.sh" "$ds" heldout
      ;;
    train)
      init=()
      shipped="$root/weights/ssr.safetensors"
      if [ "${INIT:-auto}" = auto ] && [ -f "$shipped" ] &&
        (cd "$here" && "$py" -c "import sys; from ssr.export import load_weights; sys.exit(0 if load_weights('$shipped')[0].cfg.version == 2 else 1)"); then
        init=(--init "$shipped")
      elif [ "${INIT:-auto}" != auto ] && [ "${INIT}" != none ]; then
        init=(--init "$(realpath "$INIT")")
      fi
      out="$work/runs/$run"
      resume=()
      [ -f "$out/checkpoint.pt" ] && resume=(--resume)
      args=(--data "$ds" --out "$out" --iters "${ITERS:-7000}" --batch 8 --crop 64 \
        --lr 5e-4 --workers 1 --cache memory --cache-mb 6000 --val-every "${VAL_EVERY:-1000}" --val-frames 8 \
        --log-every 50 --ckpt-every 250 --snapshot-every 500 --threads "$threads" "${init[@]}" "${resume[@]}" \
        ${TRAIN_ARGS:---thin 0.5 --thin-keep-min 0.02 --lambda ssim=10})
      if [ "${DRY_RUN:-0}" = 1 ]; then
        printf '%s\n' "${args[@]}"  # the ssr.train arguments, one a line, nothing run
      else
        (cd "$here" && "$py" -m ssr.train "${args[@]}")
      fi
      ;;
    curve)
      (cd "$here" && "$py" -m ssr.curve --run "$work/runs/$run" --data "$ds" --split test --frames 8 \
        --out "$root/weights/ssr-training.png" --json "$root/weights/ssr-training.json" \
        --previous "$root/weights/ssr-training.json" \
        --title "SSR generic: training loss and held-out PSNR (CPU, $(date -u +%F))")
      ;;
    table)
      SCENES="${SCENES:-living-room,flight-helmet,barn-lamp,procedural}" PER_FRAME="${PER_FRAME-1}" \
        "$here/table1.sh" "$ds" "$work/pred"
      ;;
    *)
      echo "campaign.sh: unknown phase '$phase' (data, heldout, train, curve, table)" >&2
      exit 2
      ;;
  esac
done
