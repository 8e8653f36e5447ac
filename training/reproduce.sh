#!/usr/bin/env bash
# Rebuilds models/rpnn-hg.onnx (+ card) from nothing: generated clouds, path-traced records,
# training, ONNX export and its onnxruntime check. Every step resumes after an interruption
# (finished shards are kept, training continues from <run>/last.pt): run it again.
#
#   bash training/reproduce.sh                          # the shipped model's settings
#   nohup bash training/reproduce.sh > out/reproduce.log 2>&1 &    # in the background
#   RECORDS=100000 EPOCHS=20 FINETUNE_EPOCHS=0 bash training/reproduce.sh  # smaller
#
# Data: fixed-count training labels (SAMPLES per record: unbiased and noisy, trained with the
# relative L2 loss), precise validation and test labels (EVAL_SAMPLES per record) from held-out
# clouds, light directions uniform in the angle gamma, density scales 10 … 300.
set -euo pipefail
cd "$(dirname "$0")/.."
# Settings are environment variables (above and below); the script takes no arguments, so one
# (e.g. --help) prints this header instead of starting hours of work.
if [ "$#" -gt 0 ]; then
  sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
  echo "reproduce.sh takes no arguments (got: $*); its settings are environment variables" >&2
  exit 2
fi
CLOUDS=${CLOUDS:-gen:150}           # or e.g. gen:150:congestus,stratus,cirrus,mixture (other kinds)
DENSITY_RANGE=${DENSITY_RANGE:-10,300}
RECORDS=${RECORDS:-1000000}
SAMPLES=${SAMPLES:-128}
VAL_RECORDS=${VAL_RECORDS:-1000}
TEST_RECORDS=${TEST_RECORDS:-2000}
EVAL_SAMPLES=${EVAL_SAMPLES:-16384}
LIGHT=${LIGHT:-uniform-gamma}
EPOCHS=${EPOCHS:-12}
MAX_MINUTES=${MAX_MINUTES:-40}
# Warm restart: resume the first run's last epoch and follow the cosine schedule of
# RESTART_EPOCHS epochs from there (its step size jumps back up, then decays to 0), keeping the
# last epoch (--select last). 0: no restart. The shipped model: 12, then 20.
RESTART_EPOCHS=${RESTART_EPOCHS:-20}
RESTART_MAX_MINUTES=${RESTART_MAX_MINUTES:-200}
LOSS=${LOSS:-rel-l2}
REL_EPS=${REL_EPS:-0.01}        # rel-l2's floor in the first two stages
# Fine-tuning stage: the restart's last weights, a fresh Adam at FINETUNE_LR (cosine) for
# FINETUNE_EPOCHS epochs with rel-l2's floor FINETUNE_EPS (0 epochs: no such stage), on the
# training set extended to FINETUNE_RECORDS records (records are a prefix of any longer run:
# the first RECORDS are those the earlier stages saw). The shipped model: 4 epochs, 0.01,
# 0.0003, 2 000 000 records.
FINETUNE_EPOCHS=${FINETUNE_EPOCHS:-4}
FINETUNE_RECORDS=${FINETUNE_RECORDS:-2000000}
FINETUNE_EPS=${FINETUNE_EPS:-0.01}
FINETUNE_LR=${FINETUNE_LR:-0.0003}
FINETUNE_MAX_MINUTES=${FINETUNE_MAX_MINUTES:-200}
# More cloud sets: SECOND_RECORDS records from the clouds of each seed in SECOND_SEEDS (150 new
# clouds per seed, none of them in the first set: train.py checks), trained together: the stage
# before's last weights fine-tuned SECOND_EPOCHS epochs (Adam SECOND_LR, cosine) keeping a moving
# average of the weights (decay EMA per step), tested on the first set's held-out clouds with
# two-stage precise labels (a relative standard error of PRECISE_NOISE, see `nimbus datagen
# --eval-noise`). 0 epochs (the default): no such stage. The shipped model: SECOND_EPOCHS=3,
# SECOND_SEEDS=3 with congestus clouds (SECOND_CLOUDS), SECOND_BLEND=0.3 (its card's command).
# SECOND_EPOCHS=3 with the defaults gives the older candidate of BENCHMARKS.md (test median
# 6.7 %, but `cumulus_side` against Mitsuba 0.073 / 0.956: not shipped).
SECOND_EPOCHS=${SECOND_EPOCHS:-0}
SECOND_SEEDS=${SECOND_SEEDS:-1 2}
SECOND_CLOUDS=${SECOND_CLOUDS:-$CLOUDS}   # their kinds, e.g. gen:150:congestus,cumulus,stratus,…
# The exported weights: (1 − SECOND_BLEND) × the stage's starting weights + SECOND_BLEND × its
# trained ones (`train.py --blend-init`, WiSE-FT; 1: the trained weights).
SECOND_BLEND=${SECOND_BLEND:-1}
SECOND_RECORDS=${SECOND_RECORDS:-1000000}
SECOND_LR=${SECOND_LR:-0.0003}
EMA=${EMA:-0.999}
PRECISE_NOISE=${PRECISE_NOISE:-0.035}
SECOND_MAX_MINUTES=${SECOND_MAX_MINUTES:-200}
DEVICE=${DEVICE:-cpu}          # datagen: cpu (the shipped set) or gpu (different random streams)
# Phase function of the medium: hg (Henyey–Greenstein g = 0.857, the shipped rpnn-hg model) or
# mie (chopped Lorenz–Mie; the shipped rpnn-mie model: PHASE=mie with its card's settings).
PHASE=${PHASE:-hg}
# First stage's starting weights (a .pt or exported ONNX model; empty: random). The shipped
# rpnn-mie model starts from models/rpnn-hg.onnx.
INIT=${INIT:-}
LR=${LR:-}                      # the first stage's Adam step (empty: train.py's default)
DATA=${DATA:-out/rpnn-$PHASE-data}
RUN=${RUN:-out/train-rpnn-$PHASE}
MODEL=${MODEL:-models/rpnn-$PHASE.onnx}

# Whole-number settings are checked now, not when their stage comes hours later.
for v in RECORDS SAMPLES VAL_RECORDS TEST_RECORDS EVAL_SAMPLES EPOCHS RESTART_EPOCHS \
         FINETUNE_EPOCHS FINETUNE_RECORDS SECOND_EPOCHS SECOND_RECORDS; do
  case "${!v}" in
    '' | *[!0-9]*) echo "reproduce.sh: $v=${!v} is not a whole number" >&2; exit 2 ;;
  esac
done
for s in $SECOND_SEEDS; do
  case "$s" in
    *[!0-9]*) echo "reproduce.sh: SECOND_SEEDS holds \`$s\`, not a whole number" >&2; exit 2 ;;
  esac
done

cargo build --release -p nimbus-cli
bash training/setup.sh
datagen() { # SPLIT-specific counts; the same --out and settings, so later calls resume
  # (SEED=… and OUT=… before the call choose another cloud set or folder.)
  ./target/release/nimbus datagen --clouds "$CLOUDS" --density-range "$DENSITY_RANGE" \
    --phase "$PHASE" --seed "${SEED:-0}" --shard-size 10000 --light "$LIGHT" \
    --samples "$SAMPLES" --eval-samples "$EVAL_SAMPLES" --device "$DEVICE" \
    --out "${OUT:-$DATA}" "$@"
}
# Validation and test sets first (small, precise), then the training records.
datagen --records 0 --val-records "$VAL_RECORDS" --test-records "$TEST_RECORDS"
datagen --records "$RECORDS" --val-records "$VAL_RECORDS" --test-records "$TEST_RECORDS"
SETTINGS="PHASE=$PHASE INIT=$INIT LR=$LR CLOUDS=$CLOUDS DENSITY_RANGE=$DENSITY_RANGE RECORDS=$RECORDS SAMPLES=$SAMPLES VAL_RECORDS=$VAL_RECORDS TEST_RECORDS=$TEST_RECORDS EVAL_SAMPLES=$EVAL_SAMPLES LIGHT=$LIGHT EPOCHS=$EPOCHS MAX_MINUTES=$MAX_MINUTES RESTART_EPOCHS=$RESTART_EPOCHS RESTART_MAX_MINUTES=$RESTART_MAX_MINUTES LOSS=$LOSS REL_EPS=$REL_EPS FINETUNE_EPOCHS=$FINETUNE_EPOCHS FINETUNE_RECORDS=$FINETUNE_RECORDS FINETUNE_EPS=$FINETUNE_EPS FINETUNE_LR=$FINETUNE_LR FINETUNE_MAX_MINUTES=$FINETUNE_MAX_MINUTES SECOND_EPOCHS=$SECOND_EPOCHS SECOND_SEEDS='$SECOND_SEEDS' SECOND_CLOUDS=$SECOND_CLOUDS SECOND_BLEND=$SECOND_BLEND SECOND_RECORDS=$SECOND_RECORDS SECOND_LR=$SECOND_LR EMA=$EMA PRECISE_NOISE=$PRECISE_NOISE SECOND_MAX_MINUTES=$SECOND_MAX_MINUTES DEVICE=$DEVICE"
train() {
  training/.venv/bin/python training/train.py --data "$DATA" --loss "$LOSS" --schedule cosine \
    --seed 0 --device auto --resume --export "$MODEL" \
    --reproduce "$SETTINGS bash training/reproduce.sh" "$@"
}
if [ ! -e "$RUN/restart/last.pt" ]; then
  train --run "$RUN" --epochs "$EPOCHS" --max-minutes "$MAX_MINUTES" --rel-eps "$REL_EPS" \
    ${INIT:+--init "$INIT"} ${LR:+--lr "$LR"}
fi
if [ "$RESTART_EPOCHS" -gt "$EPOCHS" ]; then
  # A copy of the first run, so both stay inspectable; resumed from its last epoch.
  if [ ! -e "$RUN/restart/last.pt" ]; then
    mkdir -p "$RUN/restart"
    cp "$RUN/last.pt" "$RUN/restart/last.pt"
  fi
  RUN="$RUN/restart"
  train --run "$RUN" --epochs "$RESTART_EPOCHS" --max-minutes "$RESTART_MAX_MINUTES" \
    --select last --rel-eps "$REL_EPS" ${LR:+--lr "$LR"}
fi
if [ "$FINETUNE_EPOCHS" -gt 0 ]; then
  # The curves of the stages before the fine-tuning, next to the model's.
  cp "$RUN/curves.png" "${MODEL%.onnx}-curves-base.png"
  datagen --records "$FINETUNE_RECORDS" --val-records "$VAL_RECORDS" --test-records "$TEST_RECORDS"
  # Starts from the restart's weights (--init is ignored once finetune/last.pt exists).
  INIT="$RUN/last.pt"
  RUN="$RUN/finetune"
  train --run "$RUN" --epochs "$FINETUNE_EPOCHS" --max-minutes "$FINETUNE_MAX_MINUTES" \
    --select last --init "$INIT" --rel-eps "$FINETUNE_EPS" --lr "$FINETUNE_LR"
fi
if [ "$SECOND_EPOCHS" -gt 0 ]; then
  cp "$RUN/curves.png" "${MODEL%.onnx}-curves-first.png"
  TEST_PRECISE="$DATA-test-precise"
  OUT="$TEST_PRECISE" datagen --records 0 --val-records 0 --test-records "$TEST_RECORDS" \
    --eval-noise "$PRECISE_NOISE"
  SETS=()
  for S in $SECOND_SEEDS; do
    CLOUDS="$SECOND_CLOUDS" SEED="$S" OUT="$DATA-seed$S" datagen --records "$SECOND_RECORDS" \
      --val-records "$VAL_RECORDS" --test-records 0
    SETS+=("$DATA-seed$S")
  done
  INIT="$RUN/last.pt"
  RUN="$RUN/more"
  train --data "${SETS[@]}" --test-data "$TEST_PRECISE" --run "$RUN" --epochs "$SECOND_EPOCHS" \
    --max-minutes "$SECOND_MAX_MINUTES" --select last --init "$INIT" --rel-eps "$FINETUNE_EPS" \
    --lr "$SECOND_LR" --ema "$EMA" --blend-init "$SECOND_BLEND"
fi
cp "$RUN/curves.png" "${MODEL%.onnx}-curves.png"
