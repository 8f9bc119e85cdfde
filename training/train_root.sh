#!/usr/bin/env bash
# A training root of links: OUT/train holds a link for every complete sequence folder of
# SRC/train (FRAMES frames, default 8, and sequence.json; a sequence still rendering is left
# out) and, for each sparse-light train sequence (procedural seeds 300000-399999, the
# recipe's TRAIN_SPARSE_SEEDS), REPEAT - 1 more links named SEQUENCE_x1 .. (default REPEAT 4:
# the window-lit rooms oversampled four times, as the shipped model was trained); OUT/val
# links VAL (default SRC/val). What the sixteenth and seventeenth sessions' roots
# (`ds-s16`, `ds-s17`) were, re-created from the dataset as it stands:
#
#   training/train_root.sh ~/work-data/ds ~/work-data/ds-s17 4 ~/work-data/ds-val2/val
#
# OUT is replaced (only links are ever written there; SRC is never changed).
set -euo pipefail
src="$(realpath "${1:?usage: train_root.sh SRC OUT [REPEAT] [VAL]}")"
out="$(realpath -m "${2:?usage: train_root.sh SRC OUT [REPEAT] [VAL]}")"
repeat="${3:-4}"
val="$(realpath -m "${4:-$src/val}")"
frames="${FRAMES:-8}"
[ -d "$src/train" ] || { echo "train_root.sh: $src/train: no such folder" >&2; exit 2; }
[[ "$repeat" =~ ^[1-9][0-9]*$ ]] || { echo "train_root.sh: REPEAT must be a positive integer, got '$repeat'" >&2; exit 2; }
if [ -e "$out" ]; then
  # Refuse to replace anything but a root of links made by this script.
  if find "$out" -mindepth 1 \( -path "$out/train" -o -path "$out/val" \) -prune -o -print | grep -q . ||
     { [ -d "$out/train" ] && find "$out/train" -mindepth 1 ! -type l | grep -q .; }; then
    echo "train_root.sh: $out holds more than a root of links; not replacing it" >&2
    exit 2
  fi
  rm -rf "$out"
fi
mkdir -p "$out/train"
ln -s "$val" "$out/val"
last=$(printf 'frame_%04d.exr' $((frames - 1)))
n=0 extra=0
for d in "$src"/train/*/; do
  d="${d%/}"
  name="$(basename "$d")"
  [ -f "$d/sequence.json" ] && [ -f "$d/$last" ] || continue
  ln -s "$d" "$out/train/$name"
  n=$((n + 1))
  if [[ "$name" =~ ^procedural_3[0-9]{5}_train_ ]]; then
    for k in $(seq 1 $((repeat - 1))); do
      ln -s "$d" "$out/train/${name}_x$k"
      extra=$((extra + 1))
    done
  fi
done
echo "$out: $n sequences linked, $extra repeats of sparse-light ones; val -> $val"
