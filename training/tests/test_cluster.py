"""Ray fan-out of `nimbus datagen` (training/cluster/datagen.py) on a local Ray instance: the
merged parts equal a single run record for record, also when a worker is killed mid-part."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NIMBUS = Path(os.environ.get("NIMBUS_BIN", ROOT / "target" / "release" / "nimbus"))
SCRIPT = ROOT / "training" / "cluster" / "datagen.py"
# 5 small generated clouds; 16 training records in shards of 1 so that a part has several
# shards; 32 768 samples per record keep a part busy for a few seconds.
ARGS = ["--clouds", "gen:5", "--records", "16", "--val-records", "2", "--test-records", "2",
        "--shard-size", "1", "--samples", "32768", "--eval-samples", "64", "--device", "cpu"]


@pytest.fixture(scope="module")
def nimbus():
    if not NIMBUS.is_file():
        pytest.fail(f"{NIMBUS}: build it first (`cargo build --release`; scripts/test.sh does)")
    return NIMBUS


def shard_files(d: Path) -> dict:
    m = json.loads((d / "manifest.json").read_text())
    return {f: (d / f).read_bytes() for s in m["shards"] for f in (s["x"], s["y"], s["meta"])}


def nimbus_of_part(part: str) -> tuple[int, int] | None:
    """(pid, parent pid) of the running `nimbus datagen ... --shard PART`."""
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            argv = (p / "cmdline").read_bytes().split(b"\0")
            if b"datagen" in argv and part.encode() in argv:
                ppid = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
                return int(p.name), ppid
        except (OSError, IndexError, ValueError):
            continue
    return None


def test_killed_worker_resumes_and_merge_equals_a_single_run(nimbus, tmp_path):
    single = tmp_path / "single"
    subprocess.run([str(nimbus), "datagen", *ARGS, "--out", str(single), "-q"], check=True,
                   capture_output=True, timeout=300)
    out = tmp_path / "ray"
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    driver = subprocess.Popen(
        [sys.executable, str(SCRIPT), "--parts", "2", "--num-cpus", "2", "--out", str(out),
         "--nimbus", str(nimbus), "--progress-every", "1", "--", *ARGS],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    # Kill the Ray worker of part 1 once its first shard is on disk (mid-part).
    part1 = out / "parts" / "1"
    killed = None
    deadline = time.time() + 240
    while time.time() < deadline and driver.poll() is None:
        if any(part1.glob("*_meta.npy")):
            found = nimbus_of_part("1/2")
            if found:
                pid, worker = found
                os.kill(worker, signal.SIGKILL)
                killed = worker
                break
        time.sleep(0.05)
    log, _ = driver.communicate(timeout=300)
    assert killed is not None, "part 1 finished before it could be killed:\n" + log
    assert driver.returncode == 0, log
    # The retry resumed part 1: fewer records computed than the part holds.
    line = next(l for l in log.splitlines() if l.startswith("part 1/2 done"))
    held, computed = (int(v) for v in re.search(r": (\d+) records \((\d+) computed",
                                                  line).groups())
    assert computed < held, line
    # Record for record the single run: every shard file, the same shard list, same settings.
    a, b = shard_files(single), shard_files(out)
    assert a.keys() == b.keys() and len(a) == 3 * 20
    assert all(a[f] == b[f] for f in a), [f for f in a if a[f] != b[f]]
    ms = json.loads((single / "manifest.json").read_text())
    mm = json.loads((out / "manifest.json").read_text())
    assert ms["shards"] == mm["shards"]
    assert (single / "settings.json").read_bytes() == (out / "settings.json").read_bytes()
