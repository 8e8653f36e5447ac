#!/usr/bin/env bash
# A fine-tuning stage of models/rpnn-hg.onnx made on a GPU machine in one time-boxed run: the
# GPU path tracer labels a large record set from new clouds, CUDA trains from the shipped
# weights, and the result is exported at several blends (`train.py --blend-init`) and scored on
# an independent precise test set made in the same run. Run it where a Vulkan loader is
# installed (on a machine with the GPU driver only, unpack Debian's `libvulkan1` with
# `dpkg -x`), with the binary and, for the card's test figures,
# the seed-0 precise test set (`training/reproduce.sh`'s `$DATA-test-precise`) in the checkout:
#
#   bash training/device_stage.sh [--small] OUTDIR
#
# Writes OUTDIR/data (training + validation records), OUTDIR/seed<T>-test-precise (2 000
# precise records from the held-out clouds of each seed T in TEST_SEEDS: no stage trains on them), OUTDIR/run (checkpoints,
# log, curves) and OUTDIR/w<W>/rpnn-hg.onnx + card for each blend W in BLENDS, and scores the
# starting model and each export on those records (evaluate.py). The record count grows in
# steps of RECORDS_STEP while the data generation stays within DATAGEN_SECONDS (each step resumes
# the last: records are a prefix of any longer run, and the shards are at most RECORDS_STEP
# long, so a step never recomputes one); the epochs follow from the count and TRAIN_SECONDS at
# TRAIN_RATE records/s. RECORDS=N and EPOCHS=E fix both instead (the card's reproduce line
# records them, and every other setting). A finished OUTDIR/run is refused unless RESUME=1
# (then it continues). DATAGEN_DEVICE=cpu and TRAIN_DEVICE=cpu run the stage without a GPU.
# INIT_STAGE: the command that made INIT when INIT is not a committed model (an earlier stage's
# export); the card's reproduce line runs it first.
# EXTRA_CLOUDS (e.g. gen:200:cirrus) adds one more training set per seed in EXTRA_SEEDS, of
# EXTRA_RECORDS records at EXTRA_SAMPLES samples each (OUTDIR/extra-<seed>, no validation or
# test clouds of their own), trained on together with OUTDIR/data: more records of a kind the
# held-out errors by cloud kind (evaluate.py) show to be the worst.
# `--small`: a few records on any adapter (lavapipe, CPU training), to
# test the script.
set -euo pipefail
cd "$(dirname "$0")/.."
small=0
if [ "${1:-}" = --small ]; then small=1; shift; fi
out=${1:?usage: bash training/device_stage.sh [--small] OUTDIR}
nimbus=${NIMBUS:-./target/release/nimbus}
py=${PYTHON:-python3}
INIT=${INIT:-models/rpnn-hg.onnx}
TEST_PRECISE=${TEST_PRECISE:-out/rpnn-hg-data-test-precise}
SEED=${SEED:-6}
CLOUDS=${CLOUDS:-gen:600:congestus,cumulus,stratus,congestus,cirrus,mixture}
SAMPLES=${SAMPLES:-256}
VAL_RECORDS=${VAL_RECORDS:-2000}
RECORDS_STEP=${RECORDS_STEP:-500000}
MAX_RECORDS=${MAX_RECORDS:-4000000}
DATAGEN_SECONDS=${DATAGEN_SECONDS:-140}
TRAIN_SECONDS=${TRAIN_SECONDS:-140}
TRAIN_RATE=${TRAIN_RATE:-100000}
TRAIN_CAP_MINUTES=${TRAIN_CAP_MINUTES:-3}   # train.py --max-minutes: the epochs' hard stop
PRECISE_NOISE=${PRECISE_NOISE:-0.035}
MAX_EPOCHS=${MAX_EPOCHS:-8}
LR=${LR:-0.0003}
EMA=${EMA:-0.999}
BLENDS=${BLENDS:-1 0.5 0.3}
TEST_RECORDS=${TEST_RECORDS:-2000}
TEST_SEEDS=${TEST_SEEDS:-4}
TEST_CLOUDS=${TEST_CLOUDS:-gen:150}   # the first set's clouds (training/reproduce.sh)
MAX_SAMPLES=${MAX_SAMPLES:-262144}
TRAIN_DEVICE=${TRAIN_DEVICE:-cuda}
DATAGEN_DEVICE=${DATAGEN_DEVICE:-gpu}   # cpu: the same stage on a machine without a GPU
if [ "$small" = 1 ]; then
  CLOUDS=gen:12:congestus,cumulus,stratus,congestus,cirrus,mixture; SAMPLES=16; VAL_RECORDS=40
  RECORDS_STEP=200; MAX_RECORDS=400; TEST_RECORDS=10; TRAIN_DEVICE=cpu; TRAIN_RATE=2000
  PRECISE_NOISE=0.5; BLENDS=0.5; TEST_CLOUDS=gen:10; MAX_SAMPLES=4096
  # The card's test figures from this run's own test set (no seed-0 set on a fresh machine).
  TEST_PRECISE=$out/seed$(echo "$TEST_SEEDS" | cut -d' ' -f1)-test-precise
fi
RECORDS=${RECORDS:-}
EPOCHS=${EPOCHS:-}
EXTRA_CLOUDS=${EXTRA_CLOUDS:-}
EXTRA_SEEDS=${EXTRA_SEEDS:-}
EXTRA_RECORDS=${EXTRA_RECORDS:-200000}
EXTRA_SAMPLES=${EXTRA_SAMPLES:-4096}
if [ -n "$EXTRA_CLOUDS" ] && [ -z "$EXTRA_SEEDS" ]; then
  echo "training/device_stage.sh: EXTRA_CLOUDS=$EXTRA_CLOUDS needs EXTRA_SEEDS" >&2; exit 2
fi
if [ -z "$EXTRA_CLOUDS" ] && [ -n "$EXTRA_SEEDS" ]; then
  echo "training/device_stage.sh: EXTRA_SEEDS='$EXTRA_SEEDS' without EXTRA_CLOUDS" \
    "(the kinds of cloud of the extra sets)" >&2; exit 2
fi
for t in $EXTRA_SEEDS; do
  [[ "$t" =~ ^[0-9]+$ ]] ||
    { echo "training/device_stage.sh: EXTRA_SEEDS: '$t' is not a seed" >&2; exit 2; }
done
for v in ${EXTRA_CLOUDS:+EXTRA_RECORDS EXTRA_SAMPLES} RECORDS_STEP MAX_RECORDS DATAGEN_SECONDS \
         TRAIN_SECONDS TRAIN_RATE MAX_EPOCHS \
         TEST_RECORDS VAL_RECORDS SAMPLES MAX_SAMPLES ${RECORDS:+RECORDS} ${EPOCHS:+EPOCHS}; do
  [[ "${!v}" =~ ^[1-9][0-9]*$ ]] ||
    { echo "training/device_stage.sh: $v=${!v}: expected a positive integer" >&2; exit 2; }
done
[ -f "$INIT" ] || { echo "training/device_stage.sh: INIT=$INIT: no such model" >&2; exit 2; }
if [ -e "$out/run/last.pt" ] && [ "${RESUME:-0}" != 1 ]; then
  echo "training/device_stage.sh: $out/run already holds a run (RESUME=1 continues it)" >&2
  exit 2
fi
shard=$((RECORDS_STEP < 100000 ? RECORDS_STEP : 100000))
[ $((RECORDS_STEP % shard)) = 0 ] || { echo "training/device_stage.sh: RECORDS_STEP=$RECORDS_STEP:" \
  "expected a multiple of 100000 (shards of 100 000 records)" >&2; exit 2; }
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
mkdir -p "$out"
t0=$(date +%s)
say() { echo "[device_stage $(($(date +%s) - t0)) s] $*"; }
"$nimbus" info --gpu | sed -n 1p  # (not `head`: see bench/device.sh)

# The independent test sets: the first set's clouds and settings (TEST_CLOUDS) with other seeds
# (TEST_SEEDS), two-stage precise labels, float16 descriptors (predictions move by < 1e-3
# relative).
for t in $TEST_SEEDS; do
  say "seed-$t precise test set"
  "$nimbus" datagen --clouds "$TEST_CLOUDS" --density-range 10,300 --phase hg --seed "$t" \
    --max-samples "$MAX_SAMPLES" --shard-size 10000 --light uniform-gamma --samples 128 \
    --eval-samples 16384 \
    --eval-noise "$PRECISE_NOISE" --records 0 --val-records 0 --test-records "$TEST_RECORDS" \
    --f16 --device "$DATAGEN_DEVICE" -q -o "$out/seed$t-test-precise"
done

# The card's test set: the seed-0 set (carried into the checkout) or, with --small, this run's.
[ -f "$TEST_PRECISE/manifest.json" ] || { echo "training/device_stage.sh: TEST_PRECISE=$TEST_PRECISE:" \
  "no record set (training/reproduce.sh's \$DATA-test-precise)" >&2; exit 2; }

# The training set, grown while the time allows (or RECORDS of it).
data() {
  "$nimbus" datagen --clouds "$CLOUDS" --density-range 10,300 --phase hg --seed "$SEED" \
    --shard-size "$shard" --light uniform-gamma --samples "$SAMPLES" --eval-samples 16384 \
    --records "$1" --val-records "$VAL_RECORDS" --test-records 0 --f16 \
    --device "$DATAGEN_DEVICE" -q \
    -o "$out/data"
}
records=0
d0=$(date +%s)
if [ -n "$RECORDS" ]; then
  data "$RECORDS"
  records=$RECORDS
fi
while [ -z "$RECORDS" ] && [ "$records" -lt "$MAX_RECORDS" ]; do
  s=$(date +%s)
  data $((records + RECORDS_STEP))
  records=$((records + RECORDS_STEP))
  now=$(date +%s)
  say "$records training records ($((now - s)) s for the last $RECORDS_STEP)"
  # Stop when one more step would overrun the budget.
  [ $((now - d0 + now - s)) -le "$DATAGEN_SECONDS" ] || break
done
# The extra sets (EXTRA_CLOUDS): shards of 10 000 records, one folder per seed.
extra=()
total=$records
if [ -n "$EXTRA_CLOUDS" ]; then
  for t in $EXTRA_SEEDS; do
    say "extra set: $EXTRA_RECORDS records of $EXTRA_CLOUDS, seed $t, $EXTRA_SAMPLES samples"
    "$nimbus" datagen --clouds "$EXTRA_CLOUDS" --density-range 10,300 --phase hg --seed "$t" \
      --shard-size 10000 --light uniform-gamma --samples "$EXTRA_SAMPLES" --eval-samples 16384 \
      --records "$EXTRA_RECORDS" --val-records 0 --test-records 0 --f16 \
      --device "$DATAGEN_DEVICE" -q -o "$out/extra-$t"
    extra+=("$out/extra-$t")
    total=$((total + EXTRA_RECORDS))
  done
fi
epochs=${EPOCHS:-$((TRAIN_SECONDS * TRAIN_RATE / total))}
[ "$epochs" -ge 1 ] || epochs=1
[ -n "$EPOCHS" ] || [ "$epochs" -le "$MAX_EPOCHS" ] || epochs=$MAX_EPOCHS
say "training $epochs epochs on $total records"

settings="${INIT_STAGE:+$INIT_STAGE && }INIT=$INIT TEST_PRECISE=$TEST_PRECISE TEST_SEEDS='$TEST_SEEDS' TEST_CLOUDS=$TEST_CLOUDS TEST_RECORDS=$TEST_RECORDS PRECISE_NOISE=$PRECISE_NOISE MAX_SAMPLES=$MAX_SAMPLES SEED=$SEED CLOUDS=$CLOUDS SAMPLES=$SAMPLES DATAGEN_DEVICE=$DATAGEN_DEVICE VAL_RECORDS=$VAL_RECORDS RECORDS=$records EPOCHS=$epochs LR=$LR EMA=$EMA TRAIN_CAP_MINUTES=$TRAIN_CAP_MINUTES${EXTRA_CLOUDS:+ EXTRA_CLOUDS=$EXTRA_CLOUDS EXTRA_SEEDS='$EXTRA_SEEDS' EXTRA_RECORDS=$EXTRA_RECORDS EXTRA_SAMPLES=$EXTRA_SAMPLES}"
train() { # W EXTRA...: a run's export at blend W
  local w=$1
  shift
  mkdir -p "$out/w$w"
  "$py" training/train.py --data "$out/data" ${extra[@]+"${extra[@]}"} \
    --test-data "$TEST_PRECISE" --run "$out/run" \
    --init "$INIT" --epochs "$epochs" --lr "$LR" --schedule cosine --loss rel-l2 --rel-eps 0.01 \
    --ema "$EMA" --select last --seed 0 --device "$TRAIN_DEVICE" --resume --blend-init "$w" \
    --export "$out/w$w/rpnn-hg.onnx" --max-minutes "$TRAIN_CAP_MINUTES" \
    --reproduce "$settings BLENDS=$w bash training/device_stage.sh$([ "$small" = 1 ] && echo ' --small') OUTDIR" "$@"
}
first=1
for w in $BLENDS; do
  if [ "$first" = 1 ]; then
    train "$w" --preload yes
    first=0
  else
    # The finished run again: no epoch left (a run stopped by the cap stays stopped: the time
    # spent is in its checkpoint), only the export at another blend.
    train "$w" --preload no --no-check --quiet
  fi
  say "exported w$w"
done
cp "$out/run/curves.png" "$out/run/log.csv" "$out/w$(echo "$BLENDS" | cut -d' ' -f1)/"

for t in $TEST_SEEDS; do
  for m in "$INIT" $(for w in $BLENDS; do echo "$out/w$w/rpnn-hg.onnx"; done); do
    say "seed-$t test records: $m"
    "$py" training/evaluate.py --data "$out/seed$t-test-precise" --model "$m" --split test
  done
done
say "done"
