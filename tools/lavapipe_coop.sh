#!/usr/bin/env bash
# Runs a command on a CPU Vulkan driver that has cooperative matrices: Mesa 26's lavapipe
# (8x8x8 f16 x f16 + f32 at subgroup scope), so the tensor-core convolution
# (nn/conv3x3_coop) runs and is tested on a machine without a GPU. Debian 12's Mesa 22 has
# no cooperative matrices.
#
#   tools/lavapipe_coop.sh COMMAND [ARGS...]
#
# The first call downloads Mesa's Vulkan drivers from Debian trixie-backports and what they
# need from Debian trixie (about 100 MB of packages; nothing is installed system-wide) into
# $SUBPIXEL_MESA_DIR (default ~/.cache/subpixel/mesa-coop); later calls reuse it. COMMAND
# then runs under trixie's dynamic loader and libraries with VK_DRIVER_FILES pointing at
# that lavapipe, SUBPIXEL_COOP_MATRIX=1 (unless set to 0: Mesa 26's lavapipe without the
# tensor-core kernel, e.g. for timings) and SUBPIXEL_EXPECT_COOP=1 (tests/kernels.rs then
# fails if the device came up without cooperative matrices instead of skipping them). It
# must be a dynamically linked binary (a Rust test or the `subpixel` binary), not a shell
# script. Exits 3, with the reason, when the packages cannot be fetched, so that callers can
# tell that apart from a failing test.
set -euo pipefail
dir="${SUBPIXEL_MESA_DIR:-$HOME/.cache/subpixel/mesa-coop}"
mirror="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
[ $# -gt 0 ] || { echo "usage: tools/lavapipe_coop.sh COMMAND [ARGS...]" >&2; exit 2; }
root="$dir/root"
lib="$root/usr/lib/x86_64-linux-gnu"

fetch() {
  mkdir -p "$dir/debs"
  cd "$dir"
  for suite in trixie trixie-backports; do
    curl -fsS -m 120 "$mirror/dists/$suite/main/binary-amd64/Packages.xz" | xz -d > "Packages.$suite"
  done
  # Packages by name: trixie-backports first (Mesa), then trixie; dependencies recursively
  # (first alternative, versions ignored), skipping what a dynamic binary never loads.
  python3 - "$mirror" <<'PY'
import subprocess, sys, os
mirror = sys.argv[1]
index = {}
for suite in ("trixie", "trixie-backports"):  # later suites override earlier ones
    for rec in open(f"Packages.{suite}").read().split("\n\n"):
        fields = {}
        for line in rec.splitlines():
            if ":" in line and not line.startswith(" "):
                k, v = line.split(":", 1)
                fields[k] = v.strip()
        if "Package" in fields:
            index[fields["Package"]] = fields
skip = {"debconf", "libc-bin", "dpkg", "base-files", "tzdata", "perl-base", "libgcc1", "gcc-14-base",
        "usr-is-merged", "mawk"}
queue, seen = ["mesa-vulkan-drivers", "libvulkan1", "libc6", "libstdc++6"], set()
while queue:
    name = queue.pop()
    if name in seen or name in skip:
        continue
    seen.add(name)
    rec = index.get(name)
    if rec is None:
        sys.exit(f"lavapipe_coop.sh: package {name} not found in trixie or trixie-backports")
    deb = os.path.join("debs", os.path.basename(rec["Filename"]))
    if not os.path.exists(deb):
        subprocess.run(["curl", "-fsS", "-m", "300", "-o", deb, f"{mirror}/{rec['Filename']}"], check=True)
    subprocess.run(["dpkg-deb", "-x", deb, "root"], check=True)
    for field in ("Pre-Depends", "Depends"):
        for alt in rec.get(field, "").split(","):
            dep = alt.split("|")[0].split("(")[0].split(":")[0].strip()
            if dep:
                queue.append(dep)
print(f"lavapipe_coop.sh: {len(seen)} packages in {os.getcwd()}/root")
PY
  sed "s|\"library_path\": \".*\"|\"library_path\": \"$lib/libvulkan_lvp.so\"|" \
    "$root/usr/share/vulkan/icd.d/lvp_icd.json" > "$dir/lvp.json"
  touch "$dir/ready"
}

if [ ! -f "$dir/ready" ]; then
  echo "lavapipe_coop.sh: fetching Mesa's lavapipe from Debian trixie-backports into $dir" >&2
  if ! (fetch) >&2; then
    echo "lavapipe_coop.sh: could not fetch the packages (network?); nothing was run" >&2
    exit 3
  fi
fi
export VK_DRIVER_FILES="$dir/lvp.json" VK_ICD_FILENAMES="$dir/lvp.json"
export SUBPIXEL_COOP_MATRIX="${SUBPIXEL_COOP_MATRIX:-1}"
export SUBPIXEL_EXPECT_COOP="$SUBPIXEL_COOP_MATRIX"
cmd=$(command -v "$1" || true)
[ -n "$cmd" ] || { echo "lavapipe_coop.sh: no such command: $1" >&2; exit 2; }
shift
exec "$lib/ld-linux-x86-64.so.2" --library-path "$lib" "$cmd" "$@"
