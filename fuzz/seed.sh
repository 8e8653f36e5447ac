#!/usr/bin/env bash
# Seeds the fuzz corpora from files in the repository (valid inputs the fuzzer mutates).
# Usage: bash fuzz/seed.sh   (after `cargo build --release`, which provides `nimbus generate`)
set -euo pipefail
cd "$(dirname "$0")/.."
nimbus=target/release/nimbus
for t in vol npy vdb nvdb scene onnx; do mkdir -p fuzz/corpus/$t; done
"$nimbus" generate cumulus --res 8,6,8 --out fuzz/corpus/vol/cumulus.vol >/dev/null
"$nimbus" generate stratus --res 6,4,6 --out fuzz/corpus/npy/stratus.npy >/dev/null
cp crates/scene/tests/data/*.vdb fuzz/corpus/vdb/
# the uncompressed NanoVDB file is large; the compressed ones exercise the decoders too
cp crates/scene/tests/data/cloud.nvdb crates/scene/tests/data/cloud_blosc.nvdb \
  crates/scene/tests/data/cloud_fp*.nvdb fuzz/corpus/nvdb/
cp scenes/*.toml scenes/bench/*.toml fuzz/corpus/scene/
cp crates/rpnn/tests/data/*.onnx fuzz/corpus/onnx/
echo "seeded fuzz/corpus/{vol,npy,vdb,nvdb,scene,onnx}"
