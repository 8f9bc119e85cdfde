#!/usr/bin/env bash
# The pre-registered runs of issue 11 that are still open, as registered (weights/README:
# "Thirtieth session" for F6 and F7, "Thirty-first session" for F8, "Thirty-fourth session"
# for F9, "Thirty-ninth session" for F10 and F11), and the order in which a
# new machine re-creates the data they need, so that neither has to be re-typed from prose.
#
#   training/registered.sh WORK setup       # a new machine: lavapipe and the training
#                                           # virtualenv (tools/machine_setup.sh), and the
#                                           # renderer at WORK/subpixel-dist when absent
#                                           # (`cargo build --profile dist`, ~10 min)
#   training/registered.sh WORK data [PART ...]
#                                           # PARTS (default all, in this order): train (ds-s30's
#                                           # train split, what F6-F9 need to start), val (what
#                                           # their rules need), heldout (the named held-out
#                                           # scenes, then the held-out procedural seeds), first
#                                           # (the first sequence of every procedural train
#                                           # seed up to 279: what F10 and F11 need), rest
#                                           # (dataset_recipe.sh, niced, resumable: re-running
#                                           # continues)
#   training/registered.sh WORK root [s30|s39]
#                                           # WORK/ds-s30 (the default): the root F6-F9 train
#                                           # on (checked: 177 windows of 8 frames); WORK/ds-s39:
#                                           # the root F10 and F11 train on (checked: the
#                                           # first sequence of all 280 procedural seeds)
#   training/registered.sh WORK F6|...|F11  # one run, one core (campaign.sh train); resumes
#                                           # from WORK/runs/RUN when it has a checkpoint,
#                                           # else from its newest whole checkpoint in
#                                           # weights/restore (exactly, Adam included), else
#                                           # from its committed weights-only restore point
#   training/registered.sh WORK keep F6|...|F11
#                                           # copies the run's newest whole checkpoint (its
#                                           # snapshots/it_N.pt, every 500 iterations, or its
#                                           # checkpoint.pt, every 250 and where it stopped)
#                                           # to weights/restore/RUN-itN.pt and
#                                           # drops that run's older ones there: commit it,
#                                           # and a new machine continues the run from it
#   training/registered.sh WORK all         # everything below in the registered order,
#                                           # unattended and resumable (re-running skips
#                                           # what is done): setup, data train first (what
#                                           # F10 and F11 need), root s39, F10 beside F11,
#                                           # data val, rules, data heldout rest (F6-F9,
#                                           # finished and committed, are trained again
#                                           # first only where their weights are missing:
#                                           # root, F6 beside F7, val, rules, F8 beside F9,
#                                           # rules). While runs train,
#                                           # `keep` every KEEP_EVERY seconds (default 1800);
#                                           # with COMMIT=1 it also commits weights/restore
#                                           # (that folder only), so a session cut off
#                                           # keeps its training. DRY_RUN=1 prints the steps.
#   training/registered.sh WORK rules       # engine val of F5 and the finished runs, then the
#                                           # registered rules in their order (ssr.registered)
#
# WORK is outside the repository (e.g. ~/work-data); RESTORE names the folder of whole
# checkpoints (default weights/restore); SUBPIXEL names the renderer binary
# (default WORK/subpixel-dist, a copy of `cargo build --profile dist`'s, so that rebuilding
# the repository does not change the binary under a running render).
set -euo pipefail
# The whole script is one brace group, read before any of it runs: a run of hours is not
# thrown off when the file changes under it (bash otherwise reads a script as it goes).
{
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
usage="usage: registered.sh WORK all|setup|data|root|rules|keep|F6|F7|F8|F9|F10|F11"
work="$(realpath -m "${1:?$usage}")"
what="${2:?$usage}"
py="${PYTHON:-$HOME/.cache/subpixel/venv/bin/python}"
ds="$work/ds"
bin="${SUBPIXEL:-$work/subpixel-dist}"
restore="$(realpath -m "${RESTORE:-$root/weights/restore}")"
need_bin() {
  [ -x "$bin" ] || { echo "registered.sh: no renderer at $bin (registered.sh WORK setup builds it, or set SUBPIXEL)" >&2; exit 2; }
}
# run_of F6|...|F11: the run's folder name under WORK/runs.
runs=(F6 F7 F8 F9 F10 F11)
run_of() {
  case "$1" in
    F6) echo ssr-s30-F6 ;; F7) echo ssr-s30-F7 ;; F8) echo ssr-s31-F8 ;; F9) echo ssr-s34-F9 ;;
    F10) echo ssr-s39-F10 ;; F11) echo ssr-s39-F11 ;;
  esac
}
# newest PREFIX SUFFIX: the last in sort order of the files PREFIX*SUFFIX, or nothing: the
# highest iteration of checkpoints named with zero-padded iterations (snapshots/it_N.pt,
# RUN-itN.pt in the restore folder).
newest() {
  ls "$1"*"$2" 2>/dev/null | sort | tail -n 1 || true
}

# finished_of F6|...|F11: the committed final weights of a registered run that finished in
# an earlier session (nothing for a run still open).
finished_of() {
  case "$1" in
    F6) echo "$root/weights/baselines/ssr-s30-F6.safetensors" ;;
    F7) echo "$root/weights/baselines/ssr-s30-F7.safetensors" ;;
    F8) echo "$root/weights/baselines/ssr-s31-F8.safetensors" ;;
    F9) echo "$root/weights/baselines/ssr-s34-F9.safetensors" ;;
  esac
}
# weights_of R: the run's final weights, its own (WORK/runs/RUN) or committed; nothing while
# it has not finished.
weights_of() {
  local w="$work/runs/$(run_of "$1")/weights.safetensors" c
  c="$(finished_of "$1")"
  if [ -f "$w" ]; then echo "$w"; elif [ -n "$c" ] && [ -f "$c" ]; then echo "$c"; fi
}
# finished_all R...: every one of the runs has final weights.
finished_all() {
  local r
  for r in "$@"; do [ -n "$(weights_of "$r")" ] || return 1; done
}

case "$what" in
  all)
    self="$here/registered.sh"
    # step ARGS...: one step of the chain (printed instead with DRY_RUN=1).
    step() {
      echo "== registered.sh $(date -u +%FT%TZ) $*"
      [ "${DRY_RUN:-0}" = 1 ] || "$self" "$work" "$@"
    }
    stop_if_asked() {
      if [ -e "$ds/STOP" ]; then echo "registered.sh: $ds/STOP exists: the chain stops here"; exit 0; fi
    }
    # keep_restore R...: the runs' newest checkpoints into the restore folder (and, with
    # COMMIT=1, into git, that folder alone); a run without a checkpoint yet is passed over.
    keep_restore() {
      local r
      for r in "$@"; do "$self" "$work" keep "$r" 2>/dev/null || true; done
      if [ "${COMMIT:-0}" = 1 ] && [ -d "$restore" ]; then
        git -C "$root" add -A -- "$restore" &&
          git -C "$root" commit -q -m "weights/restore: the registered runs' newest whole checkpoints ($*)" -- "$restore" ||
          true
      fi
    }
    # pair R1 R2: the runs not yet finished, side by side (one core each), logs in
    # WORK/RUN.log, their checkpoints kept while they train and once more at the end.
    pair() {
      local r pids=() names=() rc=0
      for r in "$@"; do
        local done_w
        done_w="$(weights_of "$r")"
        if [ -n "$done_w" ]; then
          echo "== registered.sh $r finished before: $done_w"
          continue
        fi
        echo "== registered.sh $(date -u +%FT%TZ) $r (log $work/$r.log)"
        [ "${DRY_RUN:-0}" = 1 ] && continue
        "$self" "$work" "$r" >> "$work/$r.log" 2>&1 &
        pids+=($!)
        names+=("$r")
      done
      [ ${#pids[@]} -gt 0 ] || return 0
      local waited=0
      while [ -n "$(jobs -rp)" ]; do  # a run still going (exited ones are not listed)
        sleep 30
        waited=$((waited + 30))
        if [ "$waited" -ge "${KEEP_EVERY:-1800}" ]; then
          keep_restore "${names[@]}"
          waited=0
        fi
      done
      for r in "${pids[@]}"; do wait "$r" || rc=$?; done
      keep_restore "${names[@]}"
      [ "$rc" = 0 ] || { echo "registered.sh: ${names[*]}: a run failed (exit $rc); see their logs" >&2; exit "$rc"; }
    }
    step setup
    # F6-F9 finished in the thirty-sixth and thirty-eighth sessions and their rules were
    # applied (F5 kept); their final weights are committed (finished_of), so a new machine
    # renders first what the open runs need: the train split of ds-s30 and the first
    # sequences of procedural seeds 110-279 (ds-s39), then F10 beside F11, then val and the
    # rules, then the rest. The order of rendering changes no image and no registration.
    step data train first
    stop_if_asked
    if ! finished_all F6 F7 F8 F9; then
      step root
      pair F6 F7
      step data val
      stop_if_asked
      step rules || true
      pair F8 F9
      step rules || true
    fi
    step root s39
    pair F10 F11
    step data val
    stop_if_asked
    step rules || true
    step data heldout rest
    ;;
  setup)
    "$root/tools/machine_setup.sh" vulkan venv
    if [ ! -x "$bin" ]; then
      (cd "$root" && cargo build --profile dist --bin subpixel)
      mkdir -p "$(dirname "$bin")"
      cp "$root/target/dist/subpixel" "$bin.tmp" && mv "$bin.tmp" "$bin"
    fi
    echo "registered.sh: set up; renderer $bin"
    ;;
  data)
    need_bin
    # The twenty-seventh session's parameters (weights/README "Thirty-first session").
    common=(SUBPIXEL="$bin" SPP=1024 TRAIN_SPP=512 VAL_SEEDS=6 BACKGROUND=8 HELDOUT_SEQUENCES=1 TEST_SEEDS=20)
    # phase [VAR=VALUE ...] PHASE ...: one run of the recipe with extra settings.
    phase() {
      local vars=()
      while [[ "$1" == *=* ]]; do vars+=("$1"); shift; done
      env "${common[@]}" "${vars[@]}" nice -n 10 "$here/dataset_recipe.sh" "$ds" "$@"
    }
    parts=("${@:3}")
    [ ${#parts[@]} -gt 0 ] || parts=(train val heldout first rest)
    for part in "${parts[@]}"; do
      case "$part" in
        train) phase PROCEDURAL=0 train
               phase TRAIN_SEEDS=0 train
               phase TRAIN_SEEDS=110 SEED_SEQUENCES=1 train ;;
        val) phase val ;;
        heldout) phase PROCEDURAL=0 heldout
                 phase heldout ;;
        first) phase TRAIN_SEEDS=280 SEED_SEQUENCES=1 train ;;
        rest) phase TRAIN_SEEDS=280 train test ;;
        *) echo "registered.sh: unknown part '$part' of data (train, val, heldout, first, rest)" >&2; exit 2 ;;
      esac
    done
    ;;
  root)
    # ds-s30: every complete train sequence of the fixed scenes, the sparse-light seeds and
    # procedural seeds 0-109 (first sequences), the sparse-light ones linked 4 times.
    # ds-s39: the same with procedural seeds 0-279 (first sequences).
    name="${3:-s30}"
    case "$name" in
      s30) last_seed=109 ;;
      s39) last_seed=279 ;;
      *) echo "registered.sh: unknown root '$name' (s30, s39)" >&2; exit 2 ;;
    esac
    tmp="$work/ds-$name-src"
    rm -rf "$tmp"
    mkdir -p "$tmp/train"
    ln -s "$ds/val" "$tmp/val"
    for d in "$ds"/train/*/; do
      name_="$(basename "$d")"
      if [[ "$name_" =~ ^procedural_([0-9]+)_train_([0-9]+)$ ]]; then
        seed=$((10#${BASH_REMATCH[1]}))
        k=$((10#${BASH_REMATCH[2]}))
        if [ "$seed" -lt 300000 ] && { [ "$seed" -gt "$last_seed" ] || [ "$k" -gt 0 ]; }; then continue; fi
      fi
      ln -s "${d%/}" "$tmp/train/$name_"
    done
    "$here/train_root.sh" "$tmp" "$work/ds-$name" 4
    if [ "$name" = s39 ]; then
      # Registered as the first sequence of every procedural seed 0-279, complete (the
      # windows after --min-reference-psnr 22 are whatever those renders give: printed).
      have=0
      for seed in $(seq 0 "$last_seed"); do
        [ -e "$work/ds-$name/train/procedural_${seed}_train_000" ] && have=$((have + 1))
      done
      echo "ds-$name: $have of the $((last_seed + 1)) procedural seeds' first sequences"
      [ "$have" = $((last_seed + 1)) ] || { echo "registered.sh: ds-$name is not the registered root yet (render incomplete: registered.sh WORK data first)" >&2; exit 1; }
    fi
    n=$(cd "$here" && "$py" -c "
from ssr.data import SequenceDataset
print(len(SequenceDataset('$work/ds-$name', 'train', window=8, crop=64, min_reference_psnr=22)))")
    echo "ds-$name: $n windows of 8 frames"
    if [ "$name" = s30 ] && [ "$n" != 177 ]; then
      echo "registered.sh: ds-s30 is not the registered root yet (177 windows registered; render incomplete?)" >&2
      exit 1
    fi
    ;;
  keep)
    r="${3:?usage: registered.sh WORK keep F6|...|F11}"
    run="$(run_of "$r")"
    [ -n "$run" ] || { echo "registered.sh: unknown run '$r' to keep (${runs[*]})" >&2; exit 2; }
    snap="$(newest "$work/runs/$run/snapshots/it_" .pt)"
    n=""
    if [ -n "$snap" ]; then n=$(basename "$snap" .pt); n=${n#it_}; fi
    # The run's own checkpoint (every 250 iterations, and where a stopped run stopped) when
    # it is further on than its newest snapshot.
    own="$work/runs/$run/checkpoint.pt"
    if [ -f "$own" ]; then
      at=$(cd "$here" && "$py" -c "import sys, torch; print(int(torch.load(sys.argv[1], map_location='cpu', weights_only=False)['iteration']))" "$own" 2>/dev/null || true)
      if [[ "$at" =~ ^[0-9]+$ ]] && { [ -z "$n" ] || [ "$at" -gt "$((10#$n))" ]; }; then
        snap="$own"
        n=$(printf '%07d' "$at")
      fi
    fi
    [ -n "$snap" ] || { echo "registered.sh: $run has no checkpoint in $work/runs/$run yet" >&2; exit 1; }
    mkdir -p "$restore"
    cp "$snap" "$restore/$run-it$n.pt.tmp" && mv "$restore/$run-it$n.pt.tmp" "$restore/$run-it$n.pt"
    for old in "$restore/$run-it"*.pt; do
      [ "$old" = "$restore/$run-it$n.pt" ] || rm -f "$old"
    done
    echo "registered.sh: kept $run at iteration $((10#$n)) as $restore/$run-it$n.pt"
    ;;
  rules)
    # Engine val of F5 and of every registered run that has finished (WORK/runs/RUN/
    # weights.safetensors, or its committed final weights: finished_of), scored and decided
    # by ssr.registered (the order of the rules).
    need_bin
    models=(F5="$root/weights/ssr.safetensors")
    for r in "${runs[@]}"; do
      w="$(weights_of "$r")"
      if [ -n "$w" ]; then
        models+=("$r=$w")
      elif [ "$r" = F6 ] || [ "$r" = F7 ]; then
        echo "registered.sh: $r has not finished (no $work/runs/$(run_of "$r")/weights.safetensors)" >&2
        exit 1
      fi
    done
    # Any tiling gives the same val to 1e-6 of the range; a fixed one skips the first tuning.
    SUBPIXEL_CONV_KERNEL="${SUBPIXEL_CONV_KERNEL:-px16-cob1-tex}" SUBPIXEL="$bin" \
      "$here/engine_val.sh" "$ds" "$work/pred-rules" "${models[@]}"
    "$bin" eval --table --json --pred "$work/pred-rules" --ref "$ds" --split val > "$work/rules-val.json"
    (cd "$here" && "$py" -m ssr.registered "$work/rules-val.json")
    ;;
  F6 | F7 | F8 | F9 | F10 | F11)
    mkdir -p "$work"
    root_ds="$work/ds-s30"
    base='--thin 0.5 --thin-keep-min 0.02 --seed 17 --lambda ssim=10 --lambda m=0 --lr 1.25e-4 --background loss --mean-correction loss --min-reference-psnr 22 --window 8 --frame-weights 1,1,1,1,1,1,1,1'
    case "$what" in
      F6) init="$root/weights/baselines/ssr-s30-F6-it4500.safetensors"; at=4500
          mc='{"emission":"background"}' ;;
      F7) init="$root/weights/baselines/ssr-s30-F7-it4000.safetensors"; at=4000
          mc='{"emission":"background","escaped":"background"}' ;;
      # F8 and F9 start from F5 as shipped when they were registered, committed as its own
      # file so that shipping another model does not change their start (or refuse their
      # checkpoints, which name the start's digest).
      F8) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0
          mc='{"emission":"background","escaped":"background","exposure":"shared"}' ;;
      F9) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0
          mc='{"emission":"background"}'; base="$base --lambda mm=5" ;;
      # F10 and F11: F6's and F9's settings from F5, on the root with procedural seeds
      # 0-279 (ds-s39): the same runs over 170 more distinct scenes.
      F10) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0; root_ds="$work/ds-s39"
          mc='{"emission":"background"}' ;;
      F11) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0; root_ds="$work/ds-s39"
          mc='{"emission":"background"}'; base="$base --lambda mm=5" ;;
    esac
    run="$(run_of "$what")"
    # A run begun part-way through its schedule keeps --init-at in its options, also when it
    # resumes (the checkpoint's config holds it); it resumes from its own checkpoint
    # (campaign.sh passes --resume), else from its newest kept one.
    extra=""
    if [ "$at" -gt 0 ]; then extra="--init-at $at"; fi
    kept="$(newest "$restore/$run-it" .pt)"
    if [ ! -f "$work/runs/$run/checkpoint.pt" ] && [ -n "$kept" ]; then
      extra="$extra --resume-from $kept"
    fi
    RUN=$run ITERS=6000 VAL_EVERY=0 THREADS=1 INIT="$init" DS="$root_ds" \
      TRAIN_ARGS="$base --model-config $mc $extra" exec "$here/campaign.sh" "$work" train
    ;;
  *)
    echo "registered.sh: unknown '$what' (all, setup, data, root, rules, keep, ${runs[*]})" >&2
    exit 2
    ;;
esac
exit
}
