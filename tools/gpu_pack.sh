#!/usr/bin/env bash
# Packs what a call on a lent GPU machine needs into .devpack/ (ignored by git; the device
# tool's `carry`): the binaries (tools/gpu_bins.sh, xz-compressed), the Vulkan loader
# packages, the shared scenes the dataset's val and train splits use (never the held-out
# ones), and wheels of the Python packages the trainer needs that the machine lacks
# (openexr, for Python 3.12). Run after `cargo build --release && cargo test --release
# --no-run`; prints the pack's size (the device tool carries at most 64 MiB with the tree).
#
#   tools/gpu_pack.sh
set -euo pipefail
cd "$(dirname "$0")/.."
scenes="${SCENES:-../shared/scenes}"
rm -rf .devbin .devpack
mkdir -p .devpack/.gl .devpack/.whl .devpack/scenes
tools/gpu_bins.sh .devbin > /dev/null
tar -C .devbin -cJf .devpack/bins.tar.xz .
# The loader, as the device README says (amd64 packages, whatever this machine is).
o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
mkdir -p /tmp/amd64/partial
apt-get "${o[@]}" update -qq
(cd .devpack/.gl && apt-get "${o[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2> /dev/null)
# The fixed training scenes and the procedural scenes' props (training/recipe_props.sh).
for s in cbox cornell-box dining-room staircase2; do
  cp -r "$scenes/$s" .devpack/scenes/
done
[ -f "$scenes/README.md" ] && cp "$scenes/README.md" .devpack/scenes/
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d .devpack/.whl "openexr==$(sed -n 's/^openexr==//p' training/requirements.txt)"
du -sh .devpack
