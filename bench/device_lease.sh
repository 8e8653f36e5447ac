#!/usr/bin/env bash
# One call of the lent GPU machine: bench/device.sh for some steps, its results packed into at
# most 8 files directly under $OUT (the device tool brings back no more files than that, and
# none deeper than two folders; a step's tables and logs lie deeper).
#
#   bash bench/device_lease.sh --steps 2 [--check-refs 9,10] [--limit SECONDS] [--small]
#
# Prepared on this machine (the GPU machine has no Rust, no network and no Vulkan loader):
#   bash ../shared/gpu/prepare.sh                   # .gl/: Debian's loader packages, once
#   cargo build --release -p nimbus-cli
#   strip -o target/nimbus-gpu target/release/nimbus  # 15 MB instead of 47: the tree travels
#                                                      # within 64 MiB
#   bash bench/device.sh --prepare-refs --steps 9,10  # steps 9 and 10's references, on the CPU
# and the call carries [".gl", "target/nimbus-gpu", "out/device_refs"]. There, this script
#   1. unpacks the loader (.gl/*.deb into /) where the machine has no libvulkan.so.1;
#   2. checks that wgpu uses a hardware GPU through Vulkan, with the NVIDIA driver's ICD file
#      if it needs it, and stops otherwise (a figure of a software or OpenGL adapter would be
#      recorded as the GPU's); `--small` (the test on lavapipe) skips that check;
#   3. says whether ONNX Runtime is there for the `ort` rows (the renderer finds python3's
#      onnxruntime itself; without it those rows read "failed" and the others stand);
#   4. with --check-refs: whether the carried references of steps 9 and 10 are the ones
#      this machine's scenes need (their keys hash the scenes' values, which its maths library
#      computes; `bench/device.sh --check-refs`, seconds), said in lease.log, so that a call
#      for those steps is not spent on references that will not match;
#   5. runs `bench/device.sh --steps STEPS` under `timeout LIMIT` (default 540 s: the tool
#      stops a call at 600 s, and a killed call brings back only what is already under $OUT);
#   6. packs into $OUT: device.md and device.csv (the figures), lease.log (this script's
#      and device.sh's output), adapter.txt, results.tgz (every table, report and log of the
#      steps; images and arrays left out), whatever the steps got done before the limit.
# Exit status: device.sh's (124: the limit, the rows before it in device.csv; 1: a step
# failed), else 1 (no binary), 2 (bad arguments), 3 (no hardware GPU).
#
# Which steps in which call, for 15 minutes of device time: docs/experiments/2026-12-07-device-run-prepared.md.
set -uo pipefail
cd "$(dirname "$0")/.."
steps=
limit=540
small=
check=
while [ $# -gt 0 ]; do
  case "$1" in
    --steps) steps="$2"; shift ;;
    --limit) limit="$2"; shift ;;
    --check-refs) check="$2"; shift ;;
    --small) small=--small ;;
    -h|--help) sed -n '2,/^set -uo/p' "$0" | sed '$d'; exit 0 ;;
    *) echo "bench/device_lease.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
[ -n "$steps" ] || { echo "bench/device_lease.sh: --steps is required (e.g. --steps 2)" >&2; exit 2; }
case "$limit" in
  ''|*[!0-9]*) echo "bench/device_lease.sh: --limit '$limit': expected whole seconds, at least 1" >&2; exit 2 ;;
esac
limit=$((10#$limit))
[ "$limit" -ge 1 ] || { echo "bench/device_lease.sh: --limit must be at least 1 s" >&2; exit 2; }
OUT=${OUT:-out/lease}
mkdir -p "$OUT"
log="$OUT/lease.log"
: > "$log"
say() { echo "$*" | tee -a "$log" >&2; }
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
if [ -z "${NIMBUS:-}" ]; then
  NIMBUS=$([ -x target/nimbus-gpu ] && echo target/nimbus-gpu || echo target/release/nimbus)
fi
export NIMBUS
[ -x "$NIMBUS" ] || { say "bench/device_lease.sh: $NIMBUS not found (build and strip it here, see --help)"; exit 1; }

# 1. The Vulkan loader, only where there is none (never over a machine's own).
# (grep -c reads to the end: `grep -q` would close the pipe early, and under pipefail
# ldconfig's SIGPIPE would read as "no loader" on a machine with a long library list.)
if ! ldconfig -p 2>/dev/null | grep -c 'libvulkan\.so\.1' > /dev/null; then
  if ls .gl/*.deb > /dev/null 2>&1; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    say "unpacked the Vulkan loader from .gl/"
  else
    say "no libvulkan.so.1 and no .gl/*.deb (bash ../shared/gpu/prepare.sh here, carry .gl)"
  fi
fi

# 2. The adapter wgpu uses.
adapter() { # the `used` line, wherever a driver's warnings put it
  "$NIMBUS" info --gpu > "$OUT/adapter.txt" 2>> "$log"
  awk '/^used / { sub(/^used +/, ""); print; exit }' "$OUT/adapter.txt"
}
used=$(adapter)
if [ -z "$small" ] && ! echo "$used" | grep -Eq '(DiscreteGpu|IntegratedGpu), Vulkan\)'; then
  icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  if [ -f "$icd" ]; then
    export VK_DRIVER_FILES=$icd
    used=$(adapter)
  fi
fi
say "adapter: ${used:-none}"
if [ -z "$small" ] && ! echo "$used" | grep -Eq '(DiscreteGpu|IntegratedGpu), Vulkan\)'; then
  say "bench/device_lease.sh: no hardware GPU through Vulkan (see $OUT/adapter.txt); nothing measured"
  exit 3
fi

# 3. ONNX Runtime for the `ort` rows.
if [ -z "${ORT_DYLIB_PATH:-}" ] && [ ! -x training/.venv/bin/python ] &&
  ! python3 -c 'import onnxruntime' > /dev/null 2>&1; then
  say "no ONNX Runtime (ORT_DYLIB_PATH, training/.venv, python3's onnxruntime): the ort rows will read failed"
fi

# 4. The carried references against this machine's scenes (seconds; before the steps, so
# that a limit they reach cannot leave it out).
if [ -n "$check" ]; then
  if timeout 120 bash bench/device.sh $small --check-refs --steps "$check" --out out/lease_check >> "$log" 2>&1; then
    say "references of steps $check: all carried ones match this machine's scenes"
  else
    say "references of steps $check: NOT all usable here (see lease.log); steps 9 and 10 would stop"
  fi
fi

# 5. The steps, under the limit (their own output into lease.log as it comes).
dir=out/lease_run
rm -rf "$dir"
say "bash bench/device.sh $small --steps $steps --out $dir (limit $limit s)"
timeout "$limit" bash bench/device.sh $small --steps "$steps" --out "$dir" >> "$log" 2>&1
rc=$?
[ "$rc" = 124 ] && say "bench/device_lease.sh: the steps ran past $limit s; the rows before are kept"

# 6. Packed into at most 8 files.
[ -f "$dir/device.csv" ] && cp "$dir/device.csv" "$OUT/"
if [ -f "$dir/device.md" ]; then
  cp "$dir/device.md" "$OUT/"
elif [ -f "$dir/device.csv" ]; then
  # Cut short before device.sh wrote its table: the same table from the rows there are.
  { if [ "$rc" = 124 ]; then echo "# Device benchmark (cut short at $limit s, $used)"
    else echo "# Device benchmark (stopped: exit $rc, $used)"; fi; echo
    echo "| measure | scene | setting | value | unit |"; echo "|---|---|---|---:|---|"
    tail -n +2 "$dir/device.csv" | awk -F, '{ printf "| %s | %s | %s | %s | %s |\n", $1, $2, $3, $4, $5 }'
  } > "$OUT/device.md"
fi
if [ -d "$dir" ]; then
  tar czf "$OUT/results.tgz" --exclude='*.exr' --exclude='*.png' --exclude='*.npy' \
    --exclude='*.vol' --exclude='*.svg' -C "$(dirname "$dir")" "$(basename "$dir")"
fi
say "bench/device_lease.sh: exit $rc; $(ls "$OUT" | tr '\n' ' ')"
exit "$rc"
