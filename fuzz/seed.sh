#!/usr/bin/env bash
# Seeds the fuzz corpora from files in the repository (valid inputs the fuzzer mutates).
# Usage: bash fuzz/seed.sh   (after `cargo build --release`, which provides `nimbus generate`)
set -euo pipefail
cd "$(dirname "$0")/.."
nimbus=target/release/nimbus
for t in vol npy vdb nvdb scene onnx exr; do mkdir -p fuzz/corpus/$t; done
"$nimbus" generate cumulus --res 8,6,8 --out fuzz/corpus/vol/cumulus.vol >/dev/null
"$nimbus" generate stratus --res 6,4,6 --out fuzz/corpus/npy/stratus.npy >/dev/null
# OpenVDB: every codec and the bad-input regressions; not the 214 kB uncompressed copy or the
# 8 GiB-when-dense far_tiles.vdb (inputs are capped at 32 kB and 16 MiB of dense grid).
for f in crates/scene/tests/data/*.vdb crates/cli/tests/bad-inputs/files/*.vdb; do
  case "$(basename "$f")" in cloud_none.vdb|far_tiles.vdb) ;; *) cp "$f" fuzz/corpus/vdb/ ;; esac
done
# the uncompressed NanoVDB file is large; the compressed ones exercise the decoders too
cp crates/scene/tests/data/cloud.nvdb crates/scene/tests/data/cloud_blosc.nvdb \
  crates/scene/tests/data/cloud_fp*.nvdb crates/cli/tests/bad-inputs/files/*.nvdb fuzz/corpus/nvdb/
cp scenes/*.toml scenes/bench/*.toml fuzz/corpus/scene/
# rpnn-micro.onnx (3.6 kB, a whole valid model) keeps the mutants of valid models small and fast.
cp crates/rpnn/tests/data/*.onnx fuzz/corpus/onnx/
# EXR: a test pattern in each of the 8 compressions, half and float (16 files, 1–8 kB).
cargo run -q --release -p nimbus-scene --example exr_codecs -- fuzz/corpus/exr
echo "seeded fuzz/corpus/{vol,npy,vdb,nvdb,scene,onnx,exr}"
