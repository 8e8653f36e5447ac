#!/usr/bin/env bash
# Everything Nimbus claims about GPU speed, measured in one run, as one CSV + Markdown table:
#   1. photon mapping per stage at 1920×1200 on the Elek 2012 Table 1 scenes (a turning sun, so
#      every frame traces, updates, upsamples and ray marches; mean over frames 2..N);
#   2. RPNN milliseconds per sample at 1280×720 under sun and sun + sky: the whole sample on
#      the GPU (network in f32 and f16, each with both kernels' tiles), the GPU network with CPU
#      shading, and ONNX Runtime, split into stages (`--timings`); under sun + sky also the
#      paper's sky directions (rpnn-dirs) on the GPU and in ONNX Runtime;
#   3. GPU path tracer camera paths/s against the CPU path tracer on scenes/refs/cumulus_side
#      at 1280×720;
#   4. `datagen --device gpu` records per hour (fixed-count labels, --samples 1024);
#   5. training records/s of training/train.py (synthetic records in the datagen layout, the
#      paper's minibatch of 1 000 and a larger one; bench/train_throughput.py);
#   6. memory at scale: a generated 1200³ cumulus (Kallweit 2017 §5's largest) written as
#      `.vol` and rendered by every estimator (CPU and GPU path tracers, photon map, RPNN at
#      2 spp), wall time, peak RSS and (nvidia-smi) GPU memory, as bench/volumes.sh measures
#      them on lavapipe;
#   7. photon mapping with final gathering (`pm`) on the Table 1 scenes at 1920×1080: ms per
#      gathered sample over the converged ring, and the live frame of the viewer (a generation
#      traced and upsampled and one sample gathered per frame, the sun turning);
#   8. error against time on the GPU: `nimbus compare` of pt-gpu, pm, pm-march and rpnn (WGSL
#      network) on the cumulus congestus against a pt-gpu reference — per method the time of
#      the first budget whose 4×4 relative error is ≤ 5 % and the speed-up at equal error of
#      its largest budget (report in DIR/compare/);
#   9. the same on the held-out clouds: `bench-suite --device gpu` (pt-gpu, pm, rpnn with the
#      whole sample on the GPU, and the papers' pm-elek2012 and rpnn-dirs) under sun and under
#      sun + sky, median speed-up and cases within the floor per sky condition
#      (DIR/suite/results.md);
#  10. the same under sun + environment map (pt-gpu, rpnn, rpnn-dirs: photon mapping takes no
#      environment map, and bench-suite leaves the methods that cannot out of that condition;
#      DIR/suite_env/results.md).
#
#   bash bench/device.sh [--small] [--steps LIST] [--out DIR] [--prepare-refs | --check-refs]
#
# Steps 9 and 10 take their references (the CPU path tracer to 1 % noise per 4×4 cloud block,
# as the CPU table's) from SUITE_REFS (default out/device_refs), and only from there: a
# missing one stops the step before anything renders. `--prepare-refs --steps 9,10` renders
# them on this machine instead (the 27 of the full size: 72 minutes on the 2-core machine,
# docs/experiments/2026-12-07-device-run-prepared.md), to be carried to the GPU's; `--check-refs` only says whether they are all there
# for this machine's scenes (seconds). With --small and no SUITE_REFS the steps render their
# own references into DIR/suite_cache. SUITE_REF replaces the reference flags (e.g.
# "--ref-device gpu --ref-time-cap 30" with SUITE_CACHED_ONLY=0 renders them on the GPU).
#
# `--steps 2,9` runs only those steps (default: all), so a machine's time can go first to what
# is unmeasured, or a run can be split into parts under a time limit (each with its own --out;
# bench/device_lease.sh runs a part as one call of a lent GPU machine).
#
# On an H200 the full run took 134 s (2026-12-04), before steps 7–10. Steps 9 and 10 run five
# and three methods on 18 and 9 scenes of 192×108 (their references prepared). `--small`
# runs the same steps at reduced sizes (1/8 of the pixels or fewer, fewer frames, beams and
# records) so lavapipe finishes in about a minute; the tests run it that way. The binary is
# ./target/release/nimbus (or $NIMBUS: the release profile keeps line tables of Nimbus' own
# code for profiling, ≈ 46 MB; `strip -o` makes a 15 MB copy to take to another machine; where
# that machine has the GPU's driver but no Vulkan loader, unpack Debian's `libvulkan1` there
# with `dpkg -x`). Needs the shared references' cumulus.vol where scenes/refs/cumulus_side.toml
# points (step 3) and a python with torch ($PYTHON, else training/.venv, else python3; step 5).
# Writes DIR/device.csv, DIR/device.md and the scale renders' output DIR/scale.log (default
# DIR: out/device).
set -euo pipefail
cd "$(dirname "$0")/.."
small=0
prepare=0
check=0
steps=1,2,3,4,5,6,7,8,9,10
out=out/device
while [ $# -gt 0 ]; do
  case "$1" in
    --small) small=1 ;;
    --prepare-refs) prepare=1 ;;
    --check-refs) check=1 ;;
    --out) out="$2"; shift ;;
    --steps) steps="$2"; shift ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
    *) echo "bench/device.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
case ",$steps," in
  *[!0-9,]*|*,,,*) echo "bench/device.sh: --steps '$steps': expected step numbers 1-10, e.g. 2,9" >&2; exit 2 ;;
esac
[ -n "${steps//,/}" ] || { echo "bench/device.sh: --steps is empty" >&2; exit 2; }
asked=
for n in ${steps//,/ }; do
  n=$((10#$n))
  [ "$n" -ge 1 ] && [ "$n" -le 10 ] ||
    { echo "bench/device.sh: --steps '$steps': there is no step $n (1-10)" >&2; exit 2; }
  asked="$asked,$n"
done
steps=${asked#,}
[ "$prepare$check" != 11 ] || { echo "bench/device.sh: --prepare-refs or --check-refs, not both" >&2; exit 2; }
if [ "$prepare" = 1 ] || [ "$check" = 1 ]; then
  # Only the references of steps 9 and 10: rendered here for a later run elsewhere, or checked.
  keep=
  for n in ${steps//,/ }; do case $n in 9|10) keep="$keep,$n" ;; esac; done
  [ -n "$keep" ] || { echo "bench/device.sh: --prepare-refs and --check-refs are about the references of steps 9 and 10; --steps $steps names neither" >&2; exit 2; }
  steps=${keep#,}
fi
want() { case ",$steps," in *",$1,"*) return 0 ;; esac; return 1; }
nimbus=${NIMBUS:-./target/release/nimbus}
[ -x "$nimbus" ] || { echo "bench/device.sh: $nimbus not found (cargo build --release -p nimbus-cli)" >&2; exit 1; }
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
mkdir -p "$out/scenes"
csv="$out/device.csv"
echo "measure,scene,setting,value,unit" > "$csv"
row() { echo "$1,$2,$3,$4,$5" >> "$csv"; }

# References for steps 9 and 10 from elsewhere (SUITE_REFS, or full size): cached only.
refs_given=$([ -n "${SUITE_REFS:-}" ] && echo 1 || echo 0)
if [ "$small" = 1 ]; then
  W=240; H=150; FRAMES=3; BEAMS=1024; RW=64; RH=36; RSPP=1; PW=128; PH=96; PTSPP=4; GPTSPP=16
  DG_RECORDS=16; DG_SAMPLES=256; VOLRES=96; TR_RECORDS=3000; TR_EPOCHS=1; TR_BATCH="1000"
  SCALE_PM="--method pm --beams 1024 --ring 20"  # the converged ring is 100 × 8 192 beams
  GW=192; GH=108; GSPP=4; GREF=2; CW=96; CH=54
  CMP_BUDGETS="--budgets pt-gpu=4,16,64 --budgets pm=1,4,16 --budgets pm-march=4,16 --budgets rpnn=1,4"
  CMP_REF="--ref-spp 64 --ref-time-cap 60"
  SUITE_SIZE=32x18
  SUITE="--clouds 1 --lights back --size $SUITE_SIZE"
  SUITE_METHODS="--methods pt-gpu,pm,pm-elek2012,rpnn,rpnn-dirs --budgets pt-gpu=4,16 --budgets pm=4 --budgets pm-elek2012=4 --budgets rpnn=2 --budgets rpnn-dirs=2 --beams 1024"
  SUITE_REF=${SUITE_REF:---ref-device cpu --ref-spp 128 --ref-noise 0}
  SUITE_REFS=${SUITE_REFS:-$out/suite_cache}
else
  W=1920; H=1200; FRAMES=12; BEAMS=8192; RW=1280; RH=720; RSPP=2; PW=1280; PH=720; PTSPP=4; GPTSPP=64
  DG_RECORDS=2000; DG_SAMPLES=1024; VOLRES=1200; TR_RECORDS=200000; TR_EPOCHS=3
  TR_BATCH="1000 8000"
  SCALE_PM="--method pm"
  GW=1920; GH=1080; GSPP=64; GREF=4; CW=960; CH=540
  CMP_BUDGETS="--budgets pt-gpu=4,16,64,256,1024 --budgets pm=1,4,16,64,256 --budgets pm-march=4,16,100 --budgets rpnn=1,4,16"
  CMP_REF="--ref-spp 1024 --ref-time-cap 300"
  SUITE_SIZE=192x108
  SUITE="--clouds 3 --size $SUITE_SIZE"
  SUITE_METHODS="--methods pt-gpu,pm,pm-elek2012,rpnn,rpnn-dirs"
  # The references of the CPU table's kind (the CPU path tracer to 1 % noise per 4×4 block),
  # rendered beforehand on another machine (--prepare-refs) and carried: none on the GPU's time.
  SUITE_REF=${SUITE_REF:---ref-device cpu --ref-spp 512 --ref-noise 0.01 --ref-time-cap 1200}
  SUITE_REFS=${SUITE_REFS:-out/device_refs}
fi
# The training environment of training/setup.sh where there is one, else python3 (with torch).
py=${PYTHON:-$([ -x training/.venv/bin/python ] && echo training/.venv/bin/python || echo python3)}
export PYTHON=$py
# A copy of a scene with another image size (relative volume paths stay valid: generators).
sized() { # SRC W H -> path
  local dst="$out/scenes/$(basename "$1" .toml)_$2x$3.toml"
  sed -e "s/^width = .*/width = $2/" -e "s/^height = .*/height = $3/" "$1" > "$dst"
  echo "$dst"
}
# (Filters that read to the end, never `head`: under pipefail a pipe closed before nimbus has
# written its last line fails the script, now and then, as the timing goes.)
adapter=$("$nimbus" info --gpu | sed -n '1s/^used *//p')
echo "adapter: $adapter" >&2

if want 1; then
# 1. Photon mapping per stage (Elek Table 1 analogue).
for spec in "altostratus 15,10,15" "cumulus_congestus 10,12,18" "wide_cloud 15,10,15"; do
  set -- $spec
  scene=$(sized "scenes/bench/$1.toml" "$W" "$H")
  "$nimbus" animate "$scene" --frames "$FRAMES" --sun-speed 0.5 --beams "$BEAMS" --ring 100 \
    --cache-res "$2" -o "$out/pm_$1" > /dev/null
  awk -F, -v s="$1" -v set="${W}x${H} I=$(echo "$2" | tr , x) n_g=$BEAMS" 'NR>2 { t+=$6; u+=$7; p+=$8; r+=$9; x+=$10; n++ }
    END { if (n == 0) exit 1;
          printf "pm_trace_ms,%s,%s,%.3f,ms\npm_update_ms,%s,%s,%.3f,ms\npm_upsample_ms,%s,%s,%.3f,ms\npm_raymarch_ms,%s,%s,%.3f,ms\npm_sun_transmittance_ms,%s,%s,%.3f,ms\npm_frame_ms,%s,%s,%.3f,ms\n",
            s,set,t/n, s,set,u/n, s,set,p/n, s,set,r/n, s,set,x/n, s,set,(t+u+p+r+x)/n }' \
    "$out/pm_$1/timings.csv" >> "$csv"
done
fi # step 1

if want 2; then
# 2. RPNN ms per sample under sun and under sun + sky (the sky head): the whole sample on the
# GPU (wgpu; its network in f32 and in f16, each with the default 64×128 tiles and with 64×64),
# the network on the GPU with CPU shading (wgpu --cpu-shading), ONNX Runtime (ort) and its int8
# copy (ort-int8, beyond the paper: the machine's CPU cores and integer units), each
# split into its stages (`--timings`): whole sample: shade, descriptor, inference, resolve (GPU
# timestamps) and the rest of the wall time; CPU shading: descriptor, inference (transfers
# included) and the rest on the CPU (camera rays, delta tracking, shadow rays).
scene=$(sized scenes/bench/rpnn_720p.toml "$RW" "$RH")
sky_scene="${scene%.toml}_sky.toml"
{ cat "$scene"; printf '\n[sky]\nradiance = [0.12, 0.2, 0.38]\n'; } > "$sky_scene"
rpnn_run() { # NAME SCENE METHOD BACKEND…: one render's ms per spp and its stages
  local name=$1 path=$2 method=$3; shift 3
  local b="$*" tag setting
  tag=$(echo "$([ "$method" = rpnn ] || echo "$method ")$b" | tr -d ' -' | sed 's/cpushading/_cpu_shading/')
  setting="${RW}x${RH} backend=$b$([ "$method" = rpnn ] || echo " method=$method")"
  # One runner that fails (ONNX Runtime missing, an adapter's limit) is a row that says so,
  # and the other runners are still measured: a lent machine's minutes are few.
  # shellcheck disable=SC2086
  if ! "$nimbus" render "$path" --method "$method" --backend $b --spp "$RSPP" --timings -q \
    -o "$out/${name}_$tag.exr" > "$out/${name}_$tag.txt" 2>&1; then
    echo "bench/device.sh: $name $setting failed; the end of $out/${name}_$tag.txt:" >&2
    tail -5 "$out/${name}_$tag.txt" >&2
    row rpnn_ms_per_spp "$name" "$setting" failed ms
    return 0
  fi
  ms=$(grep -m1 "ms per spp" "$out/${name}_$tag.txt" | sed -E 's/.* ([0-9.]+) ms per spp.*/\1/')
  row rpnn_ms_per_spp "$name" "$setting" "$ms" ms
  for stage in shade descriptor inference resolve rest; do
    ms=$(grep -m1 "^ *$stage " "$out/${name}_$tag.txt" | awk '{ print $2 }' || true)
    if [ -n "$ms" ]; then row "rpnn_${stage}_ms_per_spp" "$name" "$setting" "$ms" ms; fi
  done
}
for name in rpnn_720p rpnn_720p_sky; do
  path=$([ "$name" = rpnn_720p ] && echo "$scene" || echo "$sky_scene")
  for b in "wgpu" "wgpu --net-precision f16" "wgpu --net-tiles 64x64" \
    "wgpu --net-precision f16 --net-tiles 64x64" "wgpu --cpu-shading" "ort" "ort-int8"; do
    # shellcheck disable=SC2086
    rpnn_run "$name" "$path" rpnn $b
  done
done
# The paper's sky (`rpnn-dirs`: 4 sky directions, 5 queries per shading point) under the same
# sky, on the GPU and in ONNX Runtime: what the sky head saves.
for b in wgpu ort; do
  rpnn_run rpnn_720p_sky "$sky_scene" rpnn-dirs "$b"
done
# One query in every 4 samples (`--query-every 4`, beyond the paper; unbiased) under the same
# sky, the whole sample on the GPU and ONNX Runtime: what the network's share of a sample is
# worth on this machine (each pixel asks in one sample of four with its own offset, so every
# sample holds a quarter of the queries, at any spp).
for b in "wgpu --query-every 4" "ort --query-every 4"; do
  # shellcheck disable=SC2086
  rpnn_run rpnn_720p_sky "$sky_scene" rpnn $b
done
fi # step 2

if want 3; then
# 3. Camera paths/s: GPU path tracer against the CPU one (the shared cumulus, its volume path
# made absolute for the sized copy; at 128×96 a large GPU would sit mostly idle).
src=scenes/refs/cumulus_side.toml
vol=$(cd "$(dirname "$src")" && realpath "$(sed -n 's/^file = "\(.*\)"$/\1/p' "$(basename "$src")")")
pt_scene=$(sized "$src" "$PW" "$PH")
vol=$vol awk '/^file = / { print "file = \"" ENVIRON["vol"] "\""; next } { print }' "$pt_scene" \
  > "$pt_scene.tmp" && mv "$pt_scene.tmp" "$pt_scene"
for dev in gpu cpu; do
  spp=$([ "$dev" = gpu ] && echo "$GPTSPP" || echo "$PTSPP")
  line=$("$nimbus" render "$pt_scene" --device "$dev" --spp "$spp" -q \
    -o "$out/pt_$dev.exr" | awk '/camera paths\/s/ { if (!n++) print }')
  rate=$(echo "$line" | sed -E 's/.*\(([0-9.e+-]+) camera paths\/s.*/\1/')
  row pt_paths_per_s cumulus_side "${PW}x${PH} device=$dev spp=$spp" "$rate" paths/s
done
fi # step 3

if want 4; then
# 4. Training records per hour with the GPU path tracer.
rm -rf "$out/datagen"
line=$("$nimbus" datagen --clouds gen:5 --records "$DG_RECORDS" --val-records 0 --test-records 0 \
  --samples "$DG_SAMPLES" --device gpu --shard-size 100000 -q -o "$out/datagen" | tail -1)
rps=$(echo "$line" | sed -E 's/.*, ([0-9.]+) records\/s.*/\1/')
row datagen_records_per_hour gen:5 "device=gpu samples=$DG_SAMPLES records=$DG_RECORDS" \
  "$(awk -v r="$rps" 'BEGIN { printf "%.0f", r * 3600 }')" records/h
fi # step 4

if want 5; then
# 5. Training records/s (CUDA where torch sees a GPU).
# (found, not imported: importing torch alone takes seconds)
"$py" -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('torch') is None)" 2> /dev/null ||
  { echo "bench/device.sh: $py has no torch (bash training/setup.sh, or PYTHON=...)" >&2; exit 1; }
# shellcheck disable=SC2086
"$py" bench/train_throughput.py --records "$TR_RECORDS" --epochs "$TR_EPOCHS" --batch $TR_BATCH |
  while read -r rate dev rows batch; do
    row train_records_per_s synthetic "device=$dev batch=$batch rows=$rows" "$rate" records/s
  done
fi # step 5

if want 6; then
# 6. Memory and time at scale, every estimator (the photon map's light volumes are coarser than
# the grid when J would not fit one storage binding; the render lines, in DIR/scale.log, say
# which). Peak RSS from GNU time, else from Python's getrusage of the child; for the GPU
# estimators where nvidia-smi is there, the most GPU memory in use while the command ran
# (sampled every 100 ms, the driver's context included).
. bench/peak.sh
scale_row() { # GPU SETTING CMD...: wall time and peak RSS of CMD, and its GPU memory (GPU = 1)
  local gpu=$1 setting=$2 t0 t1 gpid="" rc=0
  shift 2
  if [ "$gpu" = 1 ] && command -v nvidia-smi > /dev/null; then
    nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 100 \
      > "$out/gpumem" 2> /dev/null &
    gpid=$!
  fi
  t0=$(date +%s.%N)
  echo "== $setting" >> "$out/scale.log"
  peak "$out/rss" "$@" >> "$out/scale.log" 2>&1 || rc=$?
  t1=$(date +%s.%N)
  if [ -n "$gpid" ]; then
    kill "$gpid" 2> /dev/null || true
    wait "$gpid" 2> /dev/null || true
  fi
  if [ "$rc" != 0 ]; then
    echo "bench/device.sh: '$setting' failed (exit $rc); its output is in $out/scale.log" >&2
    exit "$rc"
  fi
  row scale_wall_s "cumulus ${VOLRES}³ .vol" "$setting" "$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f", b - a }')" s
  row scale_peak_rss "cumulus ${VOLRES}³ .vol" "$setting" "$(cat "$out/rss" 2> /dev/null || echo "-")" MB
  if [ -n "$gpid" ]; then
    # The most of the numeric samples; "-" when the command ended before the first one.
    row scale_gpu_memory "cumulus ${VOLRES}³ .vol" "$setting" \
      "$(awk '$1 + 0 == $1 { n++; if ($1 > m) m = $1 } END { if (n) print m; else print "-" }' "$out/gpumem")" MB
  fi
}
rm -f "$out/scale.log"
scale_row 0 "generate + write .vol" "$nimbus" generate cumulus --seed 7 --res "$VOLRES,$VOLRES,$VOLRES" \
  -o "$out/scale.vol"
sed -e "s|^file = .*|file = \"$(realpath "$out/scale.vol")\"|" scenes/bench/scale.toml > "$out/scenes/scale.toml"
for m in "0 --method pt" "1 --device gpu" "1 $SCALE_PM" "1 --method rpnn --spp 2"; do
  # shellcheck disable=SC2086
  scale_row "${m%% *}" "${m#* }" "$nimbus" render "$out/scenes/scale.toml" ${m#* } -o "$out/scale_img"
done
rm -f "$out/scale.vol"
fi # step 6

if want 7; then
# 7. Photon mapping with final gathering on the Table 1 scenes: the converged ring, then GSPP
# gathered samples (ms per sample: wall time of the dispatches, synchronised), and the viewer's
# live frame with the sun turning (every frame traces and upsamples a generation and gathers one
# sample; the mean over the frames, the first included).
for s in altostratus cumulus_congestus wide_cloud; do
  scene=$(sized "scenes/bench/$s.toml" "$GW" "$GH")
  "$nimbus" render "$scene" --method pm --spp "$GSPP" --timings -q -o "$out/pmg_$s" > "$out/pmg_$s.txt"
  ms=$(grep -m1 "gathering .* ms per spp" "$out/pmg_$s.txt" | awk '{ print $2 }')
  row pm_gather_ms_per_spp "$s" "${GW}x${GH} k=1 spp=$GSPP" "$ms" ms
  ms=$(grep -m1 "ring + upsampling" "$out/pmg_$s.txt" | awk '{ print $4 }')
  row pm_gather_ring_ms "$s" "${GW}x${GH} whole ring" "$ms" ms
  # The whole image per sample (ring included), with the ring fixed and renewed every GREF
  # samples (--ring-refresh: off by default while its cost on a GPU is unmeasured).
  "$nimbus" render "$scene" --method pm --spp "$GSPP" --ring-refresh "$GREF" -q \
    -o "$out/pmr_$s" > "$out/pmr_$s.txt"
  for f in pmg pmr; do
    t=$(grep -m1 -oE "at $GSPP spp in [0-9.]+ s" "$out/${f}_$s.txt" | awk '{ print $5 }')
    r=$([ "$f" = pmr ] && echo "$GREF" || echo 0)
    row pm_gather_total_ms_per_spp "$s" "${GW}x${GH} spp=$GSPP ring-refresh=$r" \
      "$(awk -v t="$t" -v n="$GSPP" 'BEGIN { printf "%.3f", t * 1000 / n }')" ms
  done
  line=$("$nimbus" view "$scene" --headless --method pm --size "${GW}x${GH}" --frames 8 --play-sun | tail -1)
  ms=$(echo "$line" | sed -E 's/.* ([0-9.]+) ms per frame.*/\1/')
  row pm_live_frame_ms "$s" "${GW}x${GH} pm sun turning 8 frames" "$ms" ms
done
fi # step 7

if want 8; then
# 8. Error against time on this GPU (the users' table for choosing an estimator): every GPU
# estimator on one scene against a GPU path-traced reference.
cmp_scene=$(sized scenes/bench/cumulus_congestus.toml "$CW" "$CH")
# shellcheck disable=SC2086
"$nimbus" compare "$cmp_scene" --methods pt-gpu,pm,pm-march,rpnn --backend wgpu --ref-device gpu \
  $CMP_BUDGETS $CMP_REF --ref-noise 0.01 --no-cache --out "$out/compare" > "$out/compare.log" 2>&1
# report.csv (quoted fields: the device's name holds commas) → the first budget at ≤ 5 % and
# the largest budget's speed-up, per method.
"$py" - "$out/compare/report.csv" "${CW}x${CH}" >> "$csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
for m in dict.fromkeys(r["method"] for r in rows):
    rs = sorted((r for r in rows if r["method"] == m), key=lambda r: int(r["budget"]))
    hit = next((r for r in rs if float(r["rel_rmse_4x4"]) <= 0.05), None)
    if hit:
        print(f"time_to_5pct_s,cumulus_congestus,{sys.argv[2]} {m} at {hit['budget']} {hit['budget_unit']},{hit['time_s']},s")
    if rs[-1]["speedup_error"]:
        print(f"speedup_equal_error,cumulus_congestus,{sys.argv[2]} {m} at {rs[-1]['budget']} {rs[-1]['budget_unit']},{rs[-1]['speedup_error']},x")
PY
fi # step 8

# Steps 9 and 10: `bench-suite --device gpu` on the held-out clouds under SKIES into DIR/NAME,
# and its summary rows (median speed-up at equal error where finite, cases within twice the
# floor, zero included) into the CSV.
suite() { # NAME SKIES
  if [ "$check" = 1 ]; then
    # shellcheck disable=SC2086
    "$nimbus" bench-suite $SUITE $SUITE_REF --ref-cached-only --skies "$2" --methods pt \
      --budgets pt=1 --out "$out/$1_check" --work "$out/$1_work" --cache "$SUITE_REFS" \
      > "$out/$1_check.log" 2>&1 ||
      { echo "bench/device.sh: the references of $1 ($2) are not all in $SUITE_REFS:" >&2; tail -5 "$out/$1_check.log" >&2; exit 1; }
    echo "bench/device.sh: the references of $1 ($2) are all in $SUITE_REFS" >&2
    return 0
  fi
  if [ "$prepare" = 1 ]; then
    # The references alone, on this machine's CPU (the path tracer at 1 spp is the cheapest
    # method to run beside them), into SUITE_REFS.
    # shellcheck disable=SC2086
    "$nimbus" bench-suite $SUITE $SUITE_REF --skies "$2" --methods pt --budgets pt=1 \
      --out "$out/$1_refs" --work "$out/$1_work" --cache "$SUITE_REFS" > "$out/$1_refs.log" 2>&1 ||
      { echo "bench/device.sh: preparing the references failed; the end of $out/$1_refs.log:" >&2; tail -30 "$out/$1_refs.log" >&2; exit 1; }
    echo "bench/device.sh: the references of $1 ($2) are in $SUITE_REFS" >&2
    return 0
  fi
  # Full size or SUITE_REFS: only the prepared references (a missing one stops the step
  # before anything renders).
  local only=
  if { [ "$small" = 0 ] || [ "$refs_given" = 1 ]; } && [ "${SUITE_CACHED_ONLY:-1}" != 0 ]; then
    only=--ref-cached-only
  fi
  # shellcheck disable=SC2086
  "$nimbus" bench-suite --device gpu $SUITE $SUITE_METHODS $SUITE_REF $only --skies "$2" \
    --out "$out/$1" --work "$out/$1_work" --cache "$SUITE_REFS" > "$out/$1.log" 2>&1 ||
    { echo "bench/device.sh: bench-suite failed; the end of $out/$1.log:" >&2; tail -30 "$out/$1.log" >&2; exit 1; }
  "$py" - "$out/$1/results.md" "$SUITE_SIZE" >> "$csv" <<'PY'
import math, re, sys
for line in open(sys.argv[1]):
    f = [c.strip() for c in line.strip().strip("|").split("|")]
    if len(f) != 8 or f[1] not in ("sun", "sun+sky", "sun+env") or f[6].startswith("1×"):
        continue
    m = re.match(r"([0-9.e+-]+)×", f[6])
    if m and math.isfinite(float(m.group(1))) and float(m.group(1)) > 0:
        print(f"suite_speedup_median,held-out clouds {f[1]},{sys.argv[2]} {f[0]},{m.group(1)},x")
    w = re.match(r"(\d+) of (\d+)", f[5])
    if w:
        print(f"suite_within_floor,held-out clouds {f[1]},{sys.argv[2]} {f[0]} of {w.group(2)},{w.group(1)},cases")
PY
}

if want 9; then
# 9. The users' table on held-out clouds: `bench-suite --device gpu` (pt-gpu the baseline, pm,
# rpnn with the whole sample on the GPU, and the papers' variants: pm-elek2012, rpnn-dirs, whose
# sky directions the GPU sample takes under the suite's constant sky) — per method and sky
# condition the median speed-up at equal error and how many cases lie within twice their floor
# (full table in DIR/suite/results.md).
suite suite sun,sun+sky
fi # step 9

if want 10; then
# 10. The same under the sun and an environment map (the methods that take one).
suite suite_env sun+env
fi # step 10
if [ "$prepare" = 1 ] || [ "$check" = 1 ]; then exit 0; fi

# The Markdown table.
{
  echo "# Device benchmark ($(date -u +%Y-%m-%d), $adapter$([ "$small" = 1 ] && echo ', --small'))"
  echo
  echo "Command: \`bash bench/device.sh$([ "$small" = 1 ] && echo ' --small')$([ "$steps" != 1,2,3,4,5,6,7,8,9,10 ] && echo " --steps $steps")\`"
  echo
  echo "| measure | scene | setting | value | unit |"
  echo "|---|---|---|---:|---|"
  tail -n +2 "$csv" | awk -F, '{ printf "| %s | %s | %s | %s | %s |\n", $1, $2, $3, $4, $5 }'
} > "$out/device.md"
cat "$out/device.md"
