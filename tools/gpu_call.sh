# Sourced (`. tools/gpu_call.sh OUT_DIR`) by the one-call scripts of a GPU lease
# (tools/gpu_runs/*/call.sh), from the repository root on the lent machine: unpacks
# .devpack (tools/gpu_pack.sh) into $BIN (default /tmp/bin) unless it is there, sets the
# environment (tools/gpu_env.sh, the autotune cache in OUT_DIR/cache), records the GPU in
# OUT_DIR/gpu.txt, and defines
#   step NAME LIMIT COMMAND...
# which runs COMMAND with its output in OUT_DIR/NAME.log, within LIMIT seconds and what is
# left of DEADLINE (default 500) seconds since sourcing, and appends its exit status and time
# to OUT_DIR/summary.txt (a step with under 10 s left is skipped). Sets O (OUT_DIR), BIN, W
# and H (default 1920x1080). With CACHE_FROM (an earlier call's OUT_DIR), its autotune
# caches (cache/ and cache-coop/) are copied into OUT_DIR first, so nothing already tuned
# is tuned again.
O=$(realpath -m "${1:?OUT_DIR}")
mkdir -p "$O"
T0=$SECONDS
DEADLINE=${DEADLINE:-500}
W=${W:-1920} H=${H:-1080}
BIN=${BIN:-/tmp/bin}
if [ ! -x "$BIN/subpixel" ]; then
  mkdir -p "$BIN"
  python3 -c "import tarfile; tarfile.open('.devpack/bins.tar.xz').extractall('$BIN')"
  for f in .devpack/.gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
. tools/gpu_env.sh "$BIN"
export RUST_LOG=${RUST_LOG:-warn} SUBPIXEL_CACHE_DIR="$O/cache"
for c in cache cache-coop; do
  if [ -n "${CACHE_FROM:-}" ] && [ -f "$CACHE_FROM/$c/autotune.json" ]; then
    mkdir -p "$O/$c" && cp "$CACHE_FROM/$c/autotune.json" "$O/$c/"
  fi
done
step() { # name limit command...
  local name=$1 limit=$2; shift 2
  local left=$((DEADLINE - (SECONDS - T0)))
  [ "$limit" -gt "$left" ] && limit=$left
  if [ "$limit" -lt 10 ]; then echo "== $name: skipped (deadline)" | tee -a "$O/summary.txt"; return; fi
  local t0=$SECONDS
  timeout "$limit" "$@" > "$O/$name.log" 2>&1
  echo "== $name: rc $? in $((SECONDS - t0)) s" | tee -a "$O/summary.txt"
}
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.max.sm,memory.total --format=csv > "$O/gpu.txt" 2>&1
cat "$O/gpu.txt"
