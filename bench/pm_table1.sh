#!/usr/bin/env bash
# Per-stage GPU timings of photon mapping on the Elek 2012 Table 1 resolutions at 1920×1200,
# n_g = 8192 beams per frame (819 k beams in a ring of m = 100). A sun turning at 0.5°/s makes
# every frame trace, update, upsample and ray march (the exact variant also rebuilds its
# sun-transmittance volume, column "sun"). Prints the mean over frames 2..N.
# IN_SCATTER=view|lobes chooses the exact variant's in-scattering (default: the variant's);
# CACHE=default uses the default cache resolution instead of the paper's.
# Usage: [VARIANT=exact|elek2012] [IN_SCATTER=view|lobes] [CACHE=paper|default]
#        bash bench/pm_table1.sh [FRAMES]
#        (after cargo build --release -p nimbus-cli)
set -euo pipefail
frames=${1:-12}
variant=${VARIANT:-exact}
extra=()
if [ -n "${IN_SCATTER:-}" ]; then extra+=(--pm-in-scatter "$IN_SCATTER"); fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
printf "%-20s %-12s %-10s %9s %9s %9s %9s %9s %9s\n" scene D I tracing update upsample raymarch sun total
for spec in "altostratus 70x22x71 15,10,15" "cumulus_congestus 48x62x90 10,12,18" "wide_cloud 100x40x100 15,10,15"; do
  set -- $spec
  out=out/bench_pm/$variant${IN_SCATTER:+-$IN_SCATTER}${CACHE:+-$CACHE}/$1
  cache=(--cache-res "$3"); icol=$3
  if [ "${CACHE:-paper}" = default ]; then cache=(); icol=default; fi
  ./target/release/nimbus animate scenes/bench/$1.toml --frames "$frames" --sun-speed 0.5 \
    --beams 8192 --ring 100 "${cache[@]}" --pm-variant "$variant" "${extra[@]}" -o "$out" > /dev/null
  awk -F, -v s="$1" -v d="$2" -v i="$icol" 'NR>2 { t+=$6; u+=$7; p+=$8; r+=$9; x+=$10; n++ }
    END { printf "%-20s %-12s %-10s %9.2f %9.2f %9.2f %9.2f %9.2f %9.2f\n", s, d, i, t/n, u/n, p/n, r/n, x/n, (t+u+p+r+x)/n }' "$out/timings.csv"
done
