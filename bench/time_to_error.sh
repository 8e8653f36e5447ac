#!/usr/bin/env bash
# Side-by-side: Nimbus and Mitsuba 3 (llvm_ad_rgb) on shared/refs/cumulus_side, same scene,
# same metric (relative RMSE over 4×4 blocks of cloud pixels against the Mitsuba reference).
# Usage: bash bench/time_to_error.sh [SPP...]   (from the repository root, after
#        cargo build --release -p nimbus-cli; pip install mitsuba==3.9.1; apt install libllvm19)
set -euo pipefail
refs=../shared/refs
spps=("${@:-256 512 1024}")
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
mkdir -p out/bench
echo "renderer,spp,seconds,paths_per_s,rel_rmse_cloud_4x4,mean_lum_ratio"
for spp in ${spps[@]}; do
  line=$(./target/release/nimbus render scenes/refs/cumulus_side.toml -q --spp "$spp" --seed 99 \
         -o out/bench/nimbus_$spp --reference $refs/cumulus_side.exr)
  secs=$(echo "$line" | sed -n 's/.* in \([0-9.]*\) s .*/\1/p')
  pps=$(echo "$line" | sed -n 's/.*(\([0-9.e+]*\) camera paths.*/\1/p')
  r4=$(echo "$line" | awk '/rel_rmse_cloud_4x4/ {print $2}')
  mr=$(echo "$line" | awk '/mean_lum_ratio/ {print $2}')
  echo "nimbus,$spp,$secs,$pps,$r4,$mr"
  js=$(python3 bench/mitsuba_case.py $refs/cases/cumulus_side.json --spp "$spp" --seed 99 \
       --out out/bench/mitsuba_$spp.exr)
  msecs=$(echo "$js" | python3 -c 'import json,sys; print(json.load(sys.stdin)["seconds"])')
  mpps=$(echo "$js" | python3 -c 'import json,sys; print("%.3e" % json.load(sys.stdin)["paths_per_s"])')
  m=$(./target/release/nimbus compare out/bench/mitsuba_$spp.exr $refs/cumulus_side.exr)
  mr4=$(echo "$m" | awk '/rel_rmse_cloud_4x4/ {print $2}')
  mmr=$(echo "$m" | awk '/mean_lum_ratio/ {print $2}')
  echo "mitsuba-llvm,$spp,$msecs,$mpps,$mr4,$mmr"
done
