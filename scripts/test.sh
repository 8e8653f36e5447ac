#!/usr/bin/env bash
# All of Nimbus' tests, on a fresh Debian machine with a Rust toolchain and Python 3:
#
#   bash scripts/test.sh            check (and, as root, install) the system packages, then
#                                   training/setup.sh, the Rust tests and the pytest suites
#                                   (training/tests, then python/tests after `pip install ./python`)
#   bash scripts/test.sh --check    only check/install the system packages
#
# The system packages the tests need are checked before anything is compiled. Missing ones are
# installed with apt-get when that is possible (root, or passwordless sudo); otherwise the script
# stops at once and prints the exact `apt-get install …` line. NIMBUS_NO_INSTALL=1 turns the
# installation off (check only). CI (.ci/run) runs this same script.
set -euo pipefail
cd "$(dirname "$0")/.."

check_only=0
for arg in "$@"; do
  case "$arg" in
    --check) check_only=1 ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    *) echo "scripts/test.sh: unknown argument '$arg' (see --help)" >&2; exit 2 ;;
  esac
done

# ---- system packages: what each is for, and how to tell it is there ----------------------------
missing=()
need() { # need PACKAGE WHY TEST...
  local pkg="$1" why="$2"; shift 2
  if ! "$@" >/dev/null 2>&1; then
    missing+=("$pkg")
    echo "missing: $pkg ($why)" >&2
  fi
}
# (no pipes into `grep -q`: with pipefail an early grep exit fails the pipeline)
ldcache=""
has_lib() { # a shared library the dynamic loader can find
  if [ -z "$ldcache" ]; then
    ldcache="$(ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null || true)"
  fi
  [[ "$ldcache" == *"$1"* ]]
}
any_file() { local f; for f in "$@"; do [ -f "$f" ] && return 0; done; return 1; }
has_vulkan_icd() {
  any_file /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json
}
has_font() {
  [ -n "${NIMBUS_FONT:-}" ] && [ -f "$NIMBUS_FONT" ] && return 0
  any_file /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf /usr/share/fonts/TTF/DejaVuSans.ttf \
     /usr/share/fonts/dejavu/DejaVuSans.ttf
}
python_venv() { python3 -c 'import venv, ensurepip'; }

check_all() {
  missing=()
  ldcache=""
  # GPU tests run on Mesa's software Vulkan (lavapipe) when there is no GPU.
  need mesa-vulkan-drivers "a Vulkan driver: lavapipe runs the GPU tests without a GPU" has_vulkan_icd
  need libvulkan1 "the Vulkan loader wgpu opens" has_lib libvulkan.so.1
  # The viewer's window test: an X server and the X client libraries winit loads at run time.
  need xvfb "an X server for the viewer's window test" command -v Xvfb
  need xauth "X authority for Xvfb" command -v xauth
  need libx11-6 "X client library (winit)" has_lib libX11.so.6
  need libx11-xcb1 "X client library (winit)" has_lib libX11-xcb.so.1
  need libxcursor1 "X cursor library (winit)" has_lib libXcursor.so.1
  need libxrandr2 "X RandR library (winit)" has_lib libXrandr.so.2
  need libxi6 "X input library (winit)" has_lib libXi.so.6
  need libxkbcommon-x11-0 "keyboard library (winit)" has_lib libxkbcommon-x11.so.0
  # Labels of the error-against-time plots (nimbus compare).
  need fonts-dejavu-core "a TrueType font for plot labels" has_font
  # The Blosc codec of the OpenVDB reader and ONNX/protobuf build scripts are C/C++.
  need gcc "C compiler for build scripts" command -v cc
  need g++ "C++ compiler for build scripts" command -v c++
  # Peak memory in bench/device.sh and bench/volumes.sh (the device script's test checks it).
  need time "GNU time for peak RSS" test -x /usr/bin/time
  # training/setup.sh makes a virtual environment.
  need python3-venv "python3 -m venv for training/.venv" python_venv
}

check_all
if [ "${#missing[@]}" -gt 0 ]; then
  line="apt-get install -y --no-install-recommends ${missing[*]}"
  sudo=""
  if [ "$(id -u)" != 0 ] && command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    sudo="sudo -n"
  fi
  if [ "${NIMBUS_NO_INSTALL:-0}" != 1 ] && command -v apt-get >/dev/null 2>&1 \
     && { [ "$(id -u)" = 0 ] || [ -n "$sudo" ]; }; then
    echo "installing: ${missing[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get update -qq
    $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    check_all
    if [ "${#missing[@]}" -gt 0 ]; then
      echo "error: still missing after apt-get: ${missing[*]}" >&2
      exit 1
    fi
  else
    echo "error: the tests need system packages that are not installed; run as root:" >&2
    echo "  apt-get update && $line" >&2
    exit 1
  fi
fi
echo "system packages: ok" >&2
[ "$check_only" = 1 ] && exit 0

# Mesa warns without a runtime dir; the GPU tests run headless.
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
# The adapter is installed above, so a GPU test that finds none is a failure here, not a skip
# (a plain `cargo test` on a machine without one skips them with a message).
export NIMBUS_REQUIRE_GPU=1

# The training environment (pip, mostly downloading and unpacking) is made while the Rust tests
# compile; the tests that run the training scripts start only once it is complete.
setup_log="$(mktemp)"
bash training/setup.sh >"$setup_log" 2>&1 &
setup_pid=$!
# On an early exit (a compile error) the set-up is waited for, not killed: killing the shell would
# leave pip writing into training/.venv behind it.
trap 'wait "$setup_pid" 2>/dev/null || true; rm -f "$setup_log"' EXIT
cargo test --workspace --release --no-run
if ! wait "$setup_pid"; then
  cat "$setup_log" >&2
  echo "error: training/setup.sh failed (output above)" >&2
  exit 1
fi
cat "$setup_log"
cargo test --workspace --release
training/.venv/bin/python -m pytest -q training/tests
# The Python module (python/: PyO3, built by maturin) into the same environment, then its tests
# (they compare with target/release/nimbus, built above).
training/.venv/bin/pip install -q ./python
training/.venv/bin/python -m pytest -q python/tests
