#!/usr/bin/env bash
# Memory and time against cloud size (issue: clouds at the papers' scale), one Markdown table:
# grid × estimator → wall time and peak RSS (GNU time's %M), from a 128³-class cumulus to the
# sparse three-sphere file of 1999×1349×2449 voxels written by Debian's vdb_tool.
#
#   bash bench/volumes.sh [--big] [--out DIR]
#
# Needs `vdb_tool` and pyopenvdb (apt-get install libopenvdb-tools python3-openvdb) unless the
# .vdb files are already in DIR/data (copied to a GPU machine, say). Without --big: the
# 128×96×128 cumulus dense (.vol) and sparse (.vdb via pyopenvdb) and the three-sphere file
# (32-bit, 16-bit, NanoVDB): ≈ 5 minutes on 2 cores. --big adds the 1200³ cumulus (generated,
# written as a 6.9 GB .vol, rendered; ≈ 15 GB of disk, ≈ 10 minutes). Estimators that cannot
# take a grid report their error in the table (e.g. the dense copy the GPU kernels need).
# Writes DIR/volumes.md (default out/volumes); files go to DIR/data.
set -euo pipefail
cd "$(dirname "$0")/.."
big=0
out=out/volumes
while [ $# -gt 0 ]; do
  case "$1" in
    --big) big=1 ;;
    --out) out="$2"; shift ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    *) echo "bench/volumes.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
nimbus=$(realpath "${NIMBUS:-./target/release/nimbus}")
[ -x "$nimbus" ] || { echo "bench/volumes.sh: $nimbus not found (cargo build --release -p nimbus-cli)" >&2; exit 1; }
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
d="$out/data"
mkdir -p "$d"
# The .vdb files are written by Debian's tools; where they are absent (a GPU machine), files
# already in DIR/data are used and the missing ones are reported as not measured.
need() { # TOOL FILE: refuse when FILE must be made and TOOL is missing
  [ -f "$2" ] || command -v "$1" > /dev/null || {
    echo "bench/volumes.sh: $1 not found (apt-get install libopenvdb-tools python3-openvdb), and $2 is not there" >&2
    exit 1
  }
}
. bench/peak.sh
md="$out/volumes.md"
echo "| volume | voxels (box) | step | wall s | peak RSS MB | result |" > "$md"
echo "|---|---:|---|---:|---:|---|" >> "$md"

# measure LABEL VOXELS STEP -- command...: one row.
measure() {
  local label=$1 voxels=$2 step=$3
  shift 4
  local log="$d/run.log" t0 t1 rc
  t0=$(date +%s.%N)
  set +e
  peak "$d/rss" "$@" > "$log" 2>&1
  rc=$?
  set -e
  t1=$(date +%s.%N)
  local rss result
  rss=$(cat "$d/rss" 2> /dev/null || echo "-")
  if [ $rc -eq 0 ]; then result="ok"; else result="exit $rc: $(grep -m1 error "$log" | cut -c1-140)"; fi
  printf "| %s | %s | %s | %.1f | %s | %s |\n" "$label" "$voxels" "$step" "$(awk "BEGIN { print $t1 - $t0 }")" "$rss" "$result" >> "$md"
  echo "$label / $step: $result"
}

# scene FILE OUT.toml CAMERA...: the demo's light on FILE with the given box and camera.
scene() {
  local file=$1 toml=$2 box=$3 origin=$4 target=$5 scale=$6
  cat > "$toml" <<EOF
[volume]
file = "$file"
$box
density_scale = $scale
albedo = 1.0
phase = { kind = "hg", g = 0.857 }

[sun]
direction = [-0.6, 0.5, 0.62]
irradiance = [3.0, 2.85, 2.6]

[sky]
radiance = [0.12, 0.2, 0.38]

[camera]
origin = $origin
target = $target
up = [0.0, 1.0, 0.0]
vfov_deg = 40.0
width = 160
height = 100

[render]
spp = 16
seed = 1
EOF
}

# Every estimator on one scene.
estimators() {
  local label=$1 voxels=$2 toml=$3
  measure "$label" "$voxels" "pt" -- "$nimbus" render "$toml" --method pt -o "$d/img"
  measure "$label" "$voxels" "pt --device gpu" -- "$nimbus" render "$toml" --device gpu -o "$d/img"
  measure "$label" "$voxels" "pm" -- "$nimbus" render "$toml" --method pm -o "$d/img"
  measure "$label" "$voxels" "rpnn" -- "$nimbus" render "$toml" --method rpnn --spp 2 -o "$d/img"
}

# 1. The 128×96×128 cumulus, dense and sparse.
"$nimbus" generate cumulus --seed 7 --res 128,96,128 -o "$d/c128.npy" > /dev/null
"$nimbus" generate cumulus --seed 7 --res 128,96,128 -o "$d/c128.vol" > /dev/null
# Written with pyopenvdb where it is installed; elsewhere a copy already in DIR/data is used.
if /usr/bin/python3 -c "import pyopenvdb" 2> /dev/null || [ ! -f "$d/c128.vdb" ]; then
/usr/bin/python3 - "$d/c128.npy" "$d/c128.vdb" <<'PY'
import sys
import numpy as np
import pyopenvdb as vdb
a = np.load(sys.argv[1])  # [z][y][x]
g = vdb.FloatGrid()
g.copyFromArray(np.ascontiguousarray(a.transpose(2, 1, 0)), tolerance=0)
g.name = "density"
g.transform = vdb.createLinearTransform(voxelSize=2.0 / 128)
vdb.write(sys.argv[2], grids=[g])
PY
fi
cam_o="[0.5, 0.35, 3.4]"; cam_t="[0.0, 0.05, 0.0]"
scene "$(realpath "$d/c128.vol")" "$d/c128_vol.toml" "" "$cam_o" "$cam_t" 60.0
# The .vdb's box is its active voxels' (index (18..111, 10..77, 28..109) at 2/128 per voxel):
# shifted by the generator's centring so the cloud sits where the dense one does.
scene "$(realpath "$d/c128.vdb")" "$d/c128_vdb.toml" \
  'aabb_min = [-0.71875, -0.59375, -0.5625]
aabb_max = [0.75, 0.46875, 0.71875]' "$cam_o" "$cam_t" 60.0
estimators "cumulus 128×96×128 dense .vol" "1.6 M" "$d/c128_vol.toml"
estimators "cumulus 128×96×128 sparse .vdb" "0.52 M (the active box)" "$d/c128_vdb.toml"

# 2. Three fog spheres in a 1999×1349×2449 box (the issue's vdb_tool command).
spheres="-sphere voxel=0.001 radius=0.2 center=(0.2,0.2,0.2) -sphere voxel=0.001 radius=0.2 center=(1.8,1.15,2.25) -union -sphere voxel=0.001 radius=0.25 center=(1.0,0.6,1.2) -union -ls2fog name=density"
if ! command -v vdb_tool > /dev/null; then
  [ -f "$d/spheres16.vdb" ] || [ -f "$d/spheres32.vdb" ] || [ -f "$d/spheres.nvdb" ] || need vdb_tool "$d/spheres.nvdb"
elif [ ! -f "$d/spheres.nvdb" ]; then
  # shellcheck disable=SC2086
  vdb_tool $spheres -write bits=32 keep=1 "$d/spheres32.vdb" -write bits=16 keep=1 "$d/spheres16.vdb" \
    -write "$d/spheres.nvdb" > /dev/null
fi
for f in spheres32.vdb spheres16.vdb spheres.nvdb; do
  if [ ! -f "$d/$f" ]; then
    echo "| three spheres $f | 6.6 G | all | – | – | not measured: the file is not in $d (no vdb_tool here to write it) |" >> "$md"
    continue
  fi
  scene "$(realpath "$d/$f")" "$d/$f.toml" "" "[5.0, 1.0, -2.0]" "[1.0, 0.675, 1.225]" 50.0
  measure "three spheres $f" "6.6 G" "info" -- "$nimbus" info "$d/$f"
  estimators "three spheres $f" "6.6 G" "$d/$f.toml"
done

# 3. The 1200³ cumulus (Kallweit 2017 §5's largest training clouds).
if [ $big -eq 1 ]; then
  measure "cumulus 1200³" "1.73 G" "generate + write .vol" -- \
    "$nimbus" generate cumulus --seed 7 --res 1200,1200,1200 -o "$d/c1200.vol"
  scene "$(realpath "$d/c1200.vol")" "$d/c1200.toml" "" "$cam_o" "$cam_t" 60.0
  estimators "cumulus 1200³ .vol" "1.73 G" "$d/c1200.toml"
  rm -f "$d/c1200.vol"
fi
echo "wrote $md"
