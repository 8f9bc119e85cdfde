# Sourced (`. tools/gpu_env.sh BIN_DIR`) by the scripts that run on a lent GPU machine, from
# the repository root: the environment every step there needs. NVIDIA's Vulkan driver where
# the loader would not find it, no interactive device selection, unbuffered Python, and the
# path the test binaries were built in (BIN_DIR/built_in, written by tools/gpu_bins.sh)
# linked to this checkout, since they look for their data there.
export NODEVICE_SELECT=1 PYTHONUNBUFFERED=1
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
gpu_env_built_in=$(cat "${1:-.}/built_in" 2>/dev/null || true)
if [ -n "$gpu_env_built_in" ] && [ ! -e "$gpu_env_built_in" ]; then
  mkdir -p "$(dirname "$gpu_env_built_in")" && ln -s "$PWD" "$gpu_env_built_in"
fi
