#!/usr/bin/env bash
# RPNN milliseconds per sample at 1280×720 (scenes/bench/rpnn_720p.toml, sun only; add
# `--sky-dirs` scenes for sky light), split into descriptor / inference / rest, for each backend.
# Usage: bash bench/rpnn_spp.sh [SPP] [BACKENDS]   (after cargo build --release -p nimbus-cli)
set -euo pipefail
spp=${1:-2}
backends=${2:-"wgpu ort"}
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
for b in $backends; do
  echo "== backend $b, $spp spp"
  ./target/release/nimbus render scenes/bench/rpnn_720p.toml --method rpnn --backend "$b" \
    --spp "$spp" --timings -q -o "out/bench_rpnn/$b.exr"
done
