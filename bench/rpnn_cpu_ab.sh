#!/usr/bin/env bash
# RPNN's CPU sample, two builds alternated: ms per spp (descriptor / inference / rest, from
# --timings) on the bench suite's median case and a sun-only case (128×72, 32 spp), the demo
# cumulus at 320×180 (8 spp, sun and sun + sky) and at 1280×720 (1 spp).
# Usage: bash bench/rpnn_cpu_ab.sh OLD_NIMBUS [NEW_NIMBUS] [ROUNDS]
#   NEW_NIMBUS defaults to target/release/nimbus; the new build also runs --backend ort-int8.
#   The 128×72 scenes come from a bench-suite run (out/bench-suite/scenes); missing ones are
#   skipped with a note.
set -euo pipefail
old=${1:?usage: bash bench/rpnn_cpu_ab.sh OLD_NIMBUS [NEW_NIMBUS] [ROUNDS]}
new=${2:-target/release/nimbus}
rounds=${3:-3}
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
dir=out/rpnn_cpu_ab
mkdir -p "$dir"
sed -e 's/^width = 1280/width = 320/' -e 's/^height = 720/height = 180/' \
  scenes/bench/rpnn_720p.toml > "$dir/sun.toml"
{ cat "$dir/sun.toml"; printf '\n[sky]\nradiance = [0.12, 0.2, 0.38]\n'; } > "$dir/sky.toml"
run() { # binary backend scene spp label
  printf '%s %s %s %sspp: ' "$5" "$2" "$(basename "$3")" "$4"
  "$1" render "$3" --method rpnn --backend "$2" --spp "$4" --seed 1 --timings -q \
    -o "$dir/last.exr" 2>&1 | grep -E "ms per spp" | tr -s ' \n' ' '
  echo
}
cases=()
for s in stratus_009_front_sunsky cumulus_004_side_sun; do
  f=out/bench-suite/scenes/$s.toml
  if [ -f "$f" ]; then cases+=("$f 32"); else echo "note: $f missing (run nimbus bench-suite once)"; fi
done
cases+=("$dir/sun.toml 8" "$dir/sky.toml 8")
for _ in $(seq "$rounds"); do
  for c in "${cases[@]}"; do
    set -- $c
    run "$old" ort "$1" "$2" old
    run "$new" ort "$1" "$2" new
    run "$new" ort-int8 "$1" "$2" new
  done
done
for _ in $(seq $(( rounds > 1 ? rounds - 1 : 1 ))); do
  run "$old" ort scenes/bench/rpnn_720p.toml 1 old
  run "$new" ort scenes/bench/rpnn_720p.toml 1 new
  run "$new" ort-int8 scenes/bench/rpnn_720p.toml 1 new
done
