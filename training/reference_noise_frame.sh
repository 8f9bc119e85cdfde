#!/usr/bin/env bash
# Re-render one frame of every val sequence of `campaign.sh data` with a given binary and
# compare the references' noise (PSNR between their halves, `reference_noise` of
# sequence.json) with the dataset's own: an A/B of a tracer change on the data it makes.
#
#   training/reference_noise_frame.sh DS OUT [FRAME]
#
# DS is the dataset root (its val split is read, never written), OUT a new folder for the
# re-rendered frames; FRAME (default 3) the frame of each sequence. SUBPIXEL (default
# target/dist/subpixel) is the binary, SPP (default 512: TRAIN_SPP of campaign.sh) the
# reference samples, EXTRA more `subpixel dataset` options (e.g. EXTRA="--reference-noise-target
# 40 --reference-spp-max 8192"). Prints one line per sequence (with the samples each
# reference took) and the means.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
ds="$(realpath -m "${1:?usage: reference_noise_frame.sh DS OUT [FRAME]}")"
out="$(realpath -m "${2:?usage: reference_noise_frame.sh DS OUT [FRAME]}")"
frame="${3:-3}"
bin="${SUBPIXEL:-$root/target/dist/subpixel}"
spp="${SPP:-512}"
scenes="$root/../shared/scenes"
source "$here/recipe_props.sh"
for seq in "$ds"/val/*/; do
  scene=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["scene_source"])' "$seq/sequence.json")
  extra=()
  case "$scene" in builtin:procedural:*) extra=("${props[@]}") ;; esac
  "$bin" dataset --scene "$scene" --split val --first-sequence 0 --sequences 1 --frames 8 \
    --width 128 --height 128 --reference-spp "$spp" --backend cpu --background 8 \
    --frame-range "$frame..$((frame + 1))" --out "$out" "${extra[@]}" ${EXTRA:-} > /dev/null
done
python3 - "$ds/val" "$out/val" "$frame" <<'PY'
import json, os, statistics, sys
before, after, frame = sys.argv[1], sys.argv[2], "frame_%04d" % int(sys.argv[3])
rows = []
for name in sorted(os.listdir(after)):
    seq = lambda root: json.load(open(os.path.join(root, name, "sequence.json")))
    a, b = seq(before)["reference_noise"]["per_frame"][frame], seq(after)["reference_noise"]["per_frame"][frame]
    spp = seq(after).get("reference_spp_per_frame", {}).get(frame, seq(after)["reference_spp"])
    rows.append((a, b, spp))
    print(f"{name:32s} {a:6.2f} -> {b:6.2f} dB ({b - a:+.2f}) at {spp} spp")
print(f"mean over {len(rows)}: {statistics.mean(r[0] for r in rows):.2f} -> {statistics.mean(r[1] for r in rows):.2f} dB, "
      f"{statistics.mean(r[2] for r in rows):.0f} spp")
PY
