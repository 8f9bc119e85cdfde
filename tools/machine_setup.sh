#!/usr/bin/env bash
# What a fresh 2-core machine lacks, installed once (each step skipped when it is already
# there), shared by `.ci/run` and `training/registered.sh WORK setup`:
#
#   tools/machine_setup.sh vulkan   # Mesa's CPU Vulkan driver (lavapipe) when no Vulkan
#                                   # driver is present
#   tools/machine_setup.sh venv     # the training virtualenv (SUBPIXEL_VENV, default
#                                   # ~/.cache/subpixel/venv) with training/requirements.txt,
#                                   # reinstalled when the requirements change
#
# Several steps may be named at once, in order.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
for step in "$@"; do
  case "$step" in
    vulkan)
      if ! ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1 || ! ldconfig -p | grep -q libvulkan.so.1; then
        echo "== no Vulkan driver found: installing Mesa's CPU Vulkan driver (lavapipe)"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
      fi
      ;;
    venv)
      venv="${SUBPIXEL_VENV:-$HOME/.cache/subpixel/venv}"
      [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
      stamp="$venv/.requirements.sha"
      want=$(sha256sum "$root/training/requirements.txt" | cut -d' ' -f1)
      if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
        echo "== installing training/requirements.txt into $venv"
        "$venv/bin/pip" install -q -r "$root/training/requirements.txt"
        echo "$want" > "$stamp"
      fi
      ;;
    *)
      echo "machine_setup.sh: unknown step '$step' (vulkan, venv)" >&2
      exit 2
      ;;
  esac
done
