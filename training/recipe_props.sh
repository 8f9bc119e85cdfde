# Sourced by dataset_recipe.sh and sparse_light_seeds.sh: the props of the recipe's
# procedural scenes, given $scenes (the shared scenes folder): glTF files of training scenes
# and the environment map of a training scene (dining-room's); nothing of a held-out scene.
# shellcheck shell=bash
# shellcheck disable=SC2034  # used by the scripts that source this file
props=(--props "$scenes/cornell-box" --props "$scenes/cbox" --props "$scenes/staircase2"
  --props "$scenes/dining-room/env.hdr")
