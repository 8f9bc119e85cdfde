#!/usr/bin/env bash
# The pre-registered runs of issue 11, as registered (weights/README: "Thirtieth session"
# for F6 and F7, "Thirty-first session" for F8, "Thirty-fourth session" for F9,
# "Thirty-ninth session" for F10 and F11, withdrawn in the "Forty-second session", which
# registered F12, the rolling run; F13 in the "Forty-sixth session", F14 in the "Fiftieth
# session"), and the order in which a
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
#                                           # what is done): setup, rolling (F13, below),
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
# F13, the rolling run (weights/README "Forty-sixth session"), starts at iteration 8,000
# from P46 (weights/baselines/ssr-s46-P46.safetensors) and trains iterations 1,000K to
# 1,000(K+1) of its 30,000 on blocks 1 to K at once (WORK/ds-upto-K); its ledger
# (weights/prequential-F13.json) scores blocks 9 on. F12 (weights/README "Forty-second
# session", withdrawn at 12,000 in the forty-sixth; F10 and F11 were withdrawn before and
# no chain runs them) trained iterations 1,000K to 1,000(K+1) on block K alone. F14
# (weights/README "Fiftieth session") is F13 continued from its whole checkpoint at 11,250
# (committed as F14's own) on blocks rendered at 32 spp (WORK/ds-spp32-upto-K), scored on
# the 512-spp ones from block 12 (weights/prequential-F14.json); F13 is paused at 11,250.
# ROLL=F12 or F13 makes `prequential` and `rolling` drive that run (default F14). In what
# follows RUN is the rolling run:
#
#   training/registered.sh WORK block K [SPP]
#                                           # renders block K (dataset_recipe.sh phase block,
#                                           # niced, resumable) with references of SPP
#                                           # samples (default 512; others in WORK/ds-sppN)
#                                           # and links its root WORK/ds-block-K
#                                           # (WORK/ds-sppN-block-K; refused until every
#                                           # sequence of the block is complete)
#   training/registered.sh WORK F12|F13|F14 K
#                                           # trains block K on one core (--stop-at
#                                           # 1,000(K+1)); refused unless RUN's checkpoint
#                                           # (its own, else its newest kept one) is in
#                                           # [1,000K, 1,000(K+1)); done when it is past
#   training/registered.sh WORK prequential K
#                                           # K >= 9 (F12: 1): engine val over block K's 20
#                                           # procedural and 6 fixed sequences of the shipped
#                                           # model and RUN at 1,000K (before it saw them),
#                                           # the standing rule, recorded in LEDGER (default
#                                           # weights/prequential-RUN.json; ssr.prequential)
#   training/registered.sh WORK rolling [LAST]
#                                           # blocks from where RUN stands to LAST (default
#                                           # 29), unattended: each block rendered at RUN's
#                                           # samples (for F13 and F14 first the earlier ones
#                                           # a new machine lacks), RUN trains it on one core
#                                           # while the other scores it (prequential, any
#                                           # block still unscored whose weights exist; F14
#                                           # renders that block at 512 spp first) and
#                                           # renders the next; the
#                                           # checkpoint kept every KEEP_EVERY seconds and at
#                                           # every block's end (`keep RUN` also keeps the
#                                           # weights at the newest block boundary), with
#                                           # COMMIT=1 committed with the ledger
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
usage="usage: registered.sh WORK all|setup|data|root|rules|keep|block|prequential|rolling|F6|...|F14"
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
runs=(F6 F7 F8 F9 F10 F11 F12 F13 F14)
run_of() {
  case "$1" in
    F6) echo ssr-s30-F6 ;; F7) echo ssr-s30-F7 ;; F8) echo ssr-s31-F8 ;; F9) echo ssr-s34-F9 ;;
    F10) echo ssr-s39-F10 ;; F11) echo ssr-s39-F11 ;; F12) echo ssr-s42-F12 ;;
    F13) echo ssr-s46-F13 ;; F14) echo ssr-s50-F14 ;;
  esac
}
# The rolling runs' schedule: 30,000 iterations in blocks of 1,000 (block K: 1,000K to
# 1,000(K+1)). ROLL (default F14) names the rolling run that `prequential` and `rolling`
# (and so `all`) drive: F12 (withdrawn at 12,000 in the forty-sixth session), F13 (paused
# at 11,250 in the fiftieth) or F14.
roll_iters=30000
block_iters=1000
roll="${ROLL:-F14}"
case "$roll" in
  F12 | F13 | F14) ;;
  *) echo "registered.sh: ROLL must be F12, F13 or F14, got '$roll'" >&2; exit 2 ;;
esac
# The reference samples of the blocks a rolling run trains on (train_spp_of RUN): 512 (the
# registered data settings', `common` below) for F12 and F13, 32 for F14. Blocks are
# rendered a folder for each count (ds_of SPP: WORK/ds at 512, else WORK/ds-sppN) with the
# same inputs to the bit; the prequential scores always read the 512-spp ones.
train_spp_of() {
  if [ "$1" = F14 ]; then echo 32; else echo 512; fi
}
ds_of() {
  if [ "$1" = 512 ]; then echo "$work/ds"; else echo "$work/ds-spp$1"; fi
}
# block_root K [SPP]: the root of block K at SPP (default 512), ds_of SPP with -block-K
# (WORK/ds-block-K, WORK/ds-sppN-block-K); upto_dir K [SPP]: with -upto-K, blocks 1 to K.
block_root() {
  echo "$(ds_of "${2:-512}")-block-$1"
}
upto_dir() {
  echo "$(ds_of "${2:-512}")-upto-$1"
}
# first_block: the first block the rolling run's ledger scores, as ssr.prequential registers
# it (read when needed: `setup` runs before the virtualenv exists).
first_block() {
  (cd "$here" && "$py" -c "import sys; from ssr.prequential import rolling; print(rolling(sys.argv[1])['first_block'])" "$roll")
}
ledger="$(realpath -m "${LEDGER:-$root/weights/prequential-$roll.json}")"
# start_of RUN weights|iteration: where rolling run RUN starts (its weights, under the
# repository, and its iteration there: F12 from F5 at 0, F13 from P46 at 8,000), as
# ssr.prequential registers it.
start_of() {
  (cd "$here" && "$py" -c "import sys; from ssr.prequential import rolling; s = rolling(sys.argv[1])['start']; print(s[sys.argv[2]])" "$1" "$2")
}
# The options every registered run shares (F6's; each run adds its own).
base='--thin 0.5 --thin-keep-min 0.02 --seed 17 --lambda ssim=10 --lambda m=0 --lr 1.25e-4 --background loss --mean-correction loss --min-reference-psnr 22 --window 8 --frame-weights 1,1,1,1,1,1,1,1'
# The twenty-seventh session's data parameters (weights/README "Thirty-first session").
common=(SUBPIXEL="$bin" SPP=1024 TRAIN_SPP=512 VAL_SEEDS=6 BACKGROUND=8 HELDOUT_SEQUENCES=1 TEST_SEEDS=20)
# phase [VAR=VALUE ...] PHASE ...: one niced run of the recipe with extra settings.
phase() {
  local vars=()
  while [[ "$1" == *=* ]]; do vars+=("$1"); shift; done
  env "${common[@]}" "${vars[@]}" nice -n 10 "$here/dataset_recipe.sh" "$ds" "$@"
}
# block_check K: K is a block of F12's schedule.
block_check() {
  [[ "$1" =~ ^[0-9]+$ ]] && [ "$1" -lt $((roll_iters / block_iters)) ] ||
    { echo "registered.sh: block must be 0-$((roll_iters / block_iters - 1)), got '$1'" >&2; exit 2; }
}
# block_list K: block K's sequences, SPLIT/NAME a line (the recipe's ONLY_LIST).
block_list() {
  env "${common[@]}" ONLY_LIST=1 BLOCK="$1" "$here/dataset_recipe.sh" "$ds" block
}
# link_complete DIR REL...: links each complete sequence WORK/ds/REL (sequence.json and
# its 8 frames) into DIR/train; fails naming how many are not complete.
link_complete() {
  local dir="$1" rel missing=0
  shift
  rm -rf "$dir"
  mkdir -p "$dir/train"
  for rel in "$@"; do
    if [ -f "$ds/$rel/sequence.json" ] && [ -f "$ds/$rel/frame_0007.exr" ]; then
      ln -s "$ds/$rel" "$dir/train/$(basename "$rel")"
    else
      missing=$((missing + 1))
    fi
  done
  [ "$missing" = 0 ] || { echo "registered.sh: $missing of the $# sequences for $dir are not rendered yet" >&2; return 1; }
}
# checkpoint_iteration FILE: the iteration a whole checkpoint was written at.
checkpoint_iteration() {
  (cd "$here" && "$py" -c "import sys, torch; print(int(torch.load(sys.argv[1], map_location='cpu', weights_only=False)['iteration']))" "$1")
}
# iteration_of R: where the run stands: its own checkpoint's iteration, else its newest kept
# one's (named RUN-itN.pt), else where it starts (0; F13: 8,000).
iteration_of() {
  local run own kept n
  run="$(run_of "$1")"
  own="$work/runs/$run/checkpoint.pt"
  if [ -f "$own" ]; then
    checkpoint_iteration "$own" || { echo "registered.sh: cannot read the iteration of $own" >&2; return 1; }
    return 0
  fi
  kept="$(newest "$restore/$run-it" .pt)"
  if [ -n "$kept" ]; then n="$(basename "$kept" .pt)"; echo $((10#${n##*-it}));
  elif [ "$1" = F12 ] || [ "$1" = F13 ]; then start_of "$1" iteration; else echo 0; fi
}
# roll_weights N: the rolling run's weights at iteration N (its snapshot, else the kept
# ones, else its start file at its start iteration), or nothing.
roll_weights() {
  local nn w run
  nn=$(printf '%07d' "$1")
  run="$(run_of "$roll")"
  for w in "$work/runs/$run/snapshots/it_$nn.safetensors" "$restore/$run-it$nn.safetensors"; do
    [ -f "$w" ] && { echo "$w"; return 0; }
  done
  w="$root/$(start_of "$roll" weights)"
  if [ "$1" = "$(start_of "$roll" iteration)" ] && [ -f "$w" ]; then echo "$w"; fi
  return 0
}
# upto_root K [SPP]: WORK/ds-upto-K (WORK/ds-sppN-upto-K), the links to every sequence of
# blocks 1 to K's roots at SPP (what F13 and F14 train block K on); fails naming the first
# block whose root is missing.
upto_root() {
  local k="$1" spp="${2:-512}" j s b dir
  dir="$(upto_dir "$k" "$spp")"
  for j in $(seq 1 "$k"); do
    b="$(block_root "$j" "$spp")"
    [ -d "$b/train" ] || { echo "registered.sh: no $b (registered.sh WORK block $j $spp renders and links it): block $k trains on blocks 1-$k" >&2; return 1; }
  done
  rm -rf "$dir"
  mkdir -p "$dir/train"
  for j in $(seq 1 "$k"); do
    for s in "$(block_root "$j" "$spp")/train/"*; do
      if [ -e "$s" ]; then ln -sfn "$(readlink -f "$s")" "$dir/train/$(basename "$s")"; fi
    done
  done
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

self="$here/registered.sh"
stop_if_asked() {
  if [ -e "$ds/STOP" ]; then echo "registered.sh: $ds/STOP exists: the chain stops here"; exit 0; fi
}
# keep_restore R...: the runs' newest checkpoints into the restore folder (and, with
# COMMIT=1, into git: that folder and the rolling run's ledger alone); a run without a
# checkpoint yet is passed over.
keep_restore() {
  local r paths=()
  for r in "$@"; do "$self" "$work" keep "$r" 2>/dev/null || true; done
  if [ "${COMMIT:-0}" = 1 ]; then
    [ -d "$restore" ] && paths+=("$restore")
    [ -f "$ledger" ] && paths+=("$ledger")
    [ ${#paths[@]} -gt 0 ] || return 0
    git -C "$root" add -A -- "${paths[@]}" &&
      git -C "$root" commit -q -m "weights/restore: the registered runs' newest whole checkpoints ($*)" -- "${paths[@]}" ||
      true
  fi
}
# keep_while_running R...: waits for this shell's background jobs, keeping the runs'
# checkpoints every KEEP_EVERY seconds (default 1800) and once more at the end.
keep_while_running() {
  local waited=0
  while [ -n "$(jobs -rp)" ]; do  # a job still going (exited ones are not listed)
    sleep 30
    waited=$((waited + 30))
    if [ "$waited" -ge "${KEEP_EVERY:-1800}" ]; then
      keep_restore "$@"
      waited=0
    fi
  done
  keep_restore "$@"
}

case "$what" in
  all)
    # step ARGS...: one step of the chain (printed instead with DRY_RUN=1).
    step() {
      echo "== registered.sh $(date -u +%FT%TZ) $*"
      [ "${DRY_RUN:-0}" = 1 ] || "$self" "$work" "$@"
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
      keep_while_running "${names[@]}"
      for r in "${pids[@]}"; do wait "$r" || rc=$?; done
      [ "$rc" = 0 ] || { echo "registered.sh: ${names[*]}: a run failed (exit $rc); see their logs" >&2; exit "$rc"; }
    }
    step setup
    # F6-F9 finished in the thirty-sixth and thirty-eighth sessions and their rules were
    # applied (F5 kept); their final weights are committed (finished_of). F10 and F11 were
    # withdrawn before they started (forty-second session); F12 rolls over blocks, each
    # rendered beside the training of the one before, so that every session's training
    # survives in git. Then val, the rules and the rest.
    if ! finished_all F6 F7 F8 F9; then
      step data train
      stop_if_asked
      step root
      pair F6 F7
      step data val
      stop_if_asked
      step rules || true
      pair F8 F9
      step rules || true
    fi
    step rolling
    stop_if_asked
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
    r="${3:?usage: registered.sh WORK keep F6|...|F13}"
    run="$(run_of "$r")"
    [ -n "$run" ] || { echo "registered.sh: unknown run '$r' to keep (${runs[*]})" >&2; exit 2; }
    snap="$(newest "$work/runs/$run/snapshots/it_" .pt)"
    n=""
    if [ -n "$snap" ]; then n=$(basename "$snap" .pt); n=${n#it_}; fi
    # The run's own checkpoint (every 250 iterations, and where a stopped run stopped) when
    # it is further on than its newest snapshot.
    own="$work/runs/$run/checkpoint.pt"
    if [ -f "$own" ]; then
      at=$(checkpoint_iteration "$own" 2>/dev/null || true)
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
    if [ "$r" = F12 ] || [ "$r" = F13 ] || [ "$r" = F14 ]; then
      # and the weights at the newest block boundary, what block K's prequential score
      # reads (the run at 1,000K) on a machine without the run's snapshots
      w=""
      for cand in $(ls "$work/runs/$run/snapshots/"it_*.safetensors 2>/dev/null | sort -r); do
        m=$(basename "$cand" .safetensors); m=$((10#${m#it_}))
        if [ $((m % block_iters)) = 0 ]; then w="$cand"; break; fi
      done
      if [ -n "$w" ]; then
        m=$(basename "$w" .safetensors); m=${m#it_}
        cp "$w" "$restore/$run-it$m.safetensors.tmp" && mv "$restore/$run-it$m.safetensors.tmp" "$restore/$run-it$m.safetensors"
        for old in "$restore/$run-it"*.safetensors; do
          [ "$old" = "$restore/$run-it$m.safetensors" ] || rm -f "$old"
        done
        echo "registered.sh: kept $run's weights at iteration $((10#$m)) as $restore/$run-it$m.safetensors"
      fi
    fi
    ;;
  block)
    # block K [SPP]: block K with references of SPP samples (default 512) into ds_of SPP.
    k="${3:?usage: registered.sh WORK block K [SPP]}"
    spp="${4:-512}"
    block_check "$k"
    [[ "$spp" =~ ^[1-9][0-9]*$ ]] || { echo "registered.sh: reference samples must be a positive count, got '$spp'" >&2; exit 2; }
    ds="$(ds_of "$spp")"
    if [ "${DRY_RUN:-0}" != 1 ]; then
      need_bin
      phase BLOCK="$k" TRAIN_SPP="$spp" block
    fi
    mapfile -t rels < <(block_list "$k")
    dst="$(block_root "$k" "$spp")"
    link_complete "$dst-src" "${rels[@]}"
    "$here/train_root.sh" "$dst-src" "$dst" 4
    ;;
  prequential)
    k="${3:?usage: registered.sh WORK prequential K}"
    block_check "$k"
    first="$(first_block)"
    [ "$k" -ge "$first" ] || { echo "registered.sh: block $k is not scored ($roll's ledger starts at block $first)" >&2; exit 2; }
    at=$((k * block_iters))
    w="$(roll_weights "$at")"
    [ -n "$w" ] || { echo "registered.sh: no weights of $roll at iteration $at (its snapshot, or kept in $restore): it trains block $((k - 1)) first" >&2; exit 1; }
    # the block's sequences no model has seen: its procedural ones below the sparse-light
    # range, and the fixed scenes' (the guard)
    rels=()
    while read -r rel; do
      [[ "$(basename "$rel")" =~ ^procedural_3[0-9]{5}_ ]] || rels+=("$rel")
    done < <(block_list "$k")
    link_complete "$work/preq-$k" "${rels[@]}"
    shipped="$root/weights/ssr.safetensors"
    if [ "${DRY_RUN:-0}" = 1 ]; then
      echo "prequential $k: shipped=$shipped $roll=$w over ${#rels[@]} sequences"
      exit 0
    fi
    need_bin
    pred="$work/pred-preq-$k"
    rm -rf "$pred"
    # Any tiling gives the same figures to 1e-6 of the range; a fixed one skips the tuning.
    SUBPIXEL_CONV_KERNEL="${SUBPIXEL_CONV_KERNEL:-px16-cob1-tex}" SUBPIXEL="$bin" SPLIT=train \
      nice -n 10 "$here/engine_val.sh" "$work/preq-$k" "$pred" shipped="$shipped" "$roll=$w"
    "$bin" eval --table --json --pred "$pred" --ref "$work/preq-$k" --split train > "$work/preq-$k.json"
    (cd "$here" && "$py" -m ssr.prequential "$ledger" "$work/preq-$k.json" --block "$k" --iteration "$at" --challenger "$roll" \
      --shipped "sha256:$(sha256sum "$shipped" | cut -c1-16)")
    ;;
  rolling)
    last="${3:-$((roll_iters / block_iters - 1))}"
    block_check "$last"
    while :; do
      at="$(iteration_of "$roll")"
      k=$((at / block_iters))
      if [ "$at" -ge "$roll_iters" ] || [ "$k" -gt "$last" ]; then
        echo "registered.sh: $roll at iteration $at: blocks up to $last trained"
        break
      fi
      stop_if_asked
      echo "== registered.sh $(date -u +%FT%TZ) block $k ($roll at iteration $at)"
      spp="$(train_spp_of "$roll")"
      if [ "$roll" != F12 ]; then
        # F13's and F14's block K trains on blocks 1 to K: a new machine renders the
        # missing ones
        for j in $(seq 1 $((k - 1))); do
          [ -d "$(block_root "$j" "$spp")/train" ] || { "$self" "$work" block "$j" "$spp"; stop_if_asked; }
        done
      fi
      "$self" "$work" block "$k" "$spp"
      stop_if_asked
      # the other core: the blocks not yet scored whose weights exist (this one's first:
      # the run at 1,000k is where it stands; a run training on fewer samples renders the
      # 512-spp block it is scored on first, where the lane before has not), then the next
      # block's render (for such a run also the 512-spp one it will be scored on)
      scored=" $(cd "$here" && "$py" -c "import sys; from ssr.prequential import load; print(' '.join(str(e['block']) for e in load(sys.argv[1])))" "$ledger") "
      (
        for j in $(seq "$k" -1 "$(first_block)"); do
          [[ "$scored" == *" $j "* ]] && continue
          [ -n "$(roll_weights $((j * block_iters)))" ] || continue
          if [ "$spp" = 512 ] || [ -d "$(block_root "$j")/train" ] || "$self" "$work" block "$j"; then
            "$self" "$work" prequential "$j" || true
          fi
        done
        if [ "$k" -lt "$last" ]; then
          "$self" "$work" block $((k + 1)) "$spp"
          if [ "$spp" != 512 ] && [ $((k + 1)) -ge "$(first_block)" ]; then "$self" "$work" block $((k + 1)); fi
        fi
      ) >> "$work/lane.log" 2>&1 &
      echo "== registered.sh $roll block $k (log $work/$roll.log; scoring and the next render: $work/lane.log)"
      rc=0
      "$self" "$work" "$roll" "$k" >> "$work/$roll.log" 2>&1 &
      pid=$!
      keep_while_running "$roll"
      wait "$pid" || rc=$?
      [ "$rc" = 0 ] || { echo "registered.sh: $roll failed on block $k (exit $rc); see $work/$roll.log" >&2; exit "$rc"; }
      [ "$(iteration_of "$roll")" -ge $(((k + 1) * block_iters)) ] || { echo "registered.sh: $roll stopped inside block $k (a signal?)" >&2; exit 1; }
    done
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
  F6 | F7 | F8 | F9 | F10 | F11 | F12 | F13 | F14)
    mkdir -p "$work"
    root_ds="$work/ds-s30"
    iters=6000
    stop=""
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
      # F10 and F11 (withdrawn in the forty-second session, never started): F6's and F9's
      # settings from F5, on the root with procedural seeds 0-279 (ds-s39).
      F10) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0; root_ds="$work/ds-s39"
          mc='{"emission":"background"}' ;;
      F11) init="$root/weights/baselines/ssr-s29-F5.safetensors"; at=0; root_ds="$work/ds-s39"
          mc='{"emission":"background"}'; base="$base --lambda mm=5" ;;
      # F12: F9's settings from F5 over 30,000 iterations, block K (1,000K to 1,000(K+1))
      # on WORK/ds-block-K alone (withdrawn at 12,000). F13: P46's settings (F5's loss
      # weights at F5's final rate) from P46 at 8,000, block K >= 8 on blocks 1 to K at
      # once (WORK/ds-upto-K). F14: F13's settings and start (it resumes F13's whole
      # checkpoint at 11,250, committed as its own), its blocks at 32 spp
      # (WORK/ds-spp32-upto-K) with no sequence left out for its references' noise.
      F12 | F13 | F14)
          init="$root/$(start_of "$what" weights)"; at="$(start_of "$what" iteration)"
          case "$what" in
            F12) base="$base --lambda mm=5" ;;
            F13) base="$base --lr 3.125e-5" ;;
            F14) base="$base --lr 3.125e-5 --min-reference-psnr 0" ;;
          esac
          mc='{"emission":"background"}'; iters=$roll_iters
          k="${3:?usage: registered.sh WORK $what K (the block to train)}"
          block_check "$k"
          now="$(iteration_of "$what")"
          if [ "$now" -ge $(((k + 1) * block_iters)) ]; then
            echo "registered.sh: $what is at iteration $now: block $k was trained before"
            exit 0
          fi
          if [ "$now" -lt $((k * block_iters)) ]; then
            echo "registered.sh: $what is at iteration $now: block $((now / block_iters)) comes before block $k" >&2
            exit 1
          fi
          if [ "$what" = F12 ]; then
            root_ds="$work/ds-block-$k"
            [ -d "$root_ds/train" ] || { echo "registered.sh: no $root_ds (registered.sh WORK block $k renders and links it)" >&2; exit 1; }
          else
            spp="$(train_spp_of "$what")"
            upto_root "$k" "$spp"
            root_ds="$(upto_dir "$k" "$spp")"
          fi
          stop="--stop-at $(((k + 1) * block_iters))" ;;
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
    RUN=$run ITERS=$iters VAL_EVERY=0 THREADS=1 INIT="$init" DS="$root_ds" \
      TRAIN_ARGS="$base --model-config $mc $stop $extra" exec "$here/campaign.sh" "$work" train
    ;;
  *)
    echo "registered.sh: unknown '$what' (all, setup, data, root, rules, keep, block, prequential, rolling, ${runs[*]})" >&2
    exit 2
    ;;
esac
exit
}
