#!/usr/bin/env bash
# Rebuilds models/rpnn-hg.onnx (+ card) from nothing: generated clouds, path-traced records,
# training, ONNX export and its onnxruntime check. Deterministic for the given counts on the CPU
# (records are seeded by index, so a larger RECORDS extends the same set).
#
#   bash training/reproduce.sh                 # the shipped model's settings
#   RECORDS=50000 DEVICE=gpu bash training/reproduce.sh   # bigger, with the GPU path tracer
set -euo pipefail
cd "$(dirname "$0")/.."
RECORDS=${RECORDS:-7250}
TEST_RECORDS=${TEST_RECORDS:-500}
EPOCHS=${EPOCHS:-400}
DEVICE=${DEVICE:-cpu}          # datagen: cpu (the shipped set) or gpu (different random streams)
DATA=${DATA:-out/rpnn-hg}
RUN=${RUN:-out/train-rpnn-hg}
MODEL=${MODEL:-models/rpnn-hg.onnx}

cargo build --release -p nimbus-cli
./target/release/nimbus datagen --clouds gen:40 --phase hg --seed 0 --shard-size 250 \
  --records "$RECORDS" --test-records "$TEST_RECORDS" --device "$DEVICE" --out "$DATA"
bash training/setup.sh
training/.venv/bin/python training/train.py --data "$DATA" --run "$RUN" --epochs "$EPOCHS" \
  --seed 0 --device auto --export "$MODEL" \
  --reproduce "RECORDS=$RECORDS TEST_RECORDS=$TEST_RECORDS EPOCHS=$EPOCHS DEVICE=$DEVICE bash training/reproduce.sh"
