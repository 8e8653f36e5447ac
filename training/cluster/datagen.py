#!/usr/bin/env python3
"""RPNN data generation fanned out over a Ray cluster: one Ray task per part of the set.

    python training/cluster/datagen.py --parts 8 --out out/rpnn-data -- \\
        --clouds gen:150 --records 1000000 --samples 128 --eval-samples 16384 --light uniform-gamma

Each task runs ``nimbus datagen ARGS --shard K/N --out OUT/parts/K`` (the records a single run
with ARGS writes for part K, byte for byte) and is retried when it fails or its worker dies; a
retry resumes the part from the shards already on disk, so a killed worker loses at most the
shard it was writing. When all parts are done, ``nimbus datagen merge`` checks them (settings,
no gaps or overlaps, checksums) and assembles OUT as one data set for ``training/train.py``.

Locally (the tests): ``--num-cpus 2`` starts a private Ray instance. On a cluster: ``--address
auto`` from a node of it, or ``ray job submit`` (training/CLUSTER.md); the ``nimbus`` binary and
OUT must be at the same paths on every node (a shared file system).
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, type=Path,
                   help="the merged data set; the parts go to OUT/parts/K")
    p.add_argument("--parts", type=int, required=True, help="N: parts (Ray tasks) of the set")
    p.add_argument("--nimbus", type=Path, default=ROOT / "target" / "release" / "nimbus",
                   help="the nimbus binary (the same path on every node)")
    p.add_argument("--address", default=None,
                   help="Ray cluster address (`auto`: the cluster this node belongs to); "
                        "default: a private local instance")
    p.add_argument("--num-cpus", type=int, default=None,
                   help="CPUs of the private local instance (default: all)")
    p.add_argument("--cpus-per-part", type=int, default=1,
                   help="CPUs reserved per task (also nimbus's thread count)")
    p.add_argument("--retries", type=int, default=3,
                   help="retries of a part whose task fails or whose worker dies")
    p.add_argument("--progress-every", type=float, default=10.0,
                   help="seconds between progress lines")
    p.add_argument("datagen", nargs=argparse.REMAINDER,
                   help="-- then the `nimbus datagen` arguments (no --out, no --shard)")
    a = p.parse_args(argv)
    if a.datagen and a.datagen[0] == "--":
        a.datagen = a.datagen[1:]
    for bad in ("--out", "-o", "--shard"):
        if any(x == bad or x.startswith(bad + "=") for x in a.datagen):
            p.error(f"{bad} is set by this script; leave it out of the datagen arguments")
    if a.parts < 1 or a.cpus_per_part < 1 or a.retries < 0:
        p.error("--parts and --cpus-per-part must be >= 1, --retries >= 0")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from rpnn import safe_io

    try:
        # A program, not read into memory: no size bound.
        safe_io.check_regular(a.nimbus, max_bytes=1 << 62, what="the nimbus binary")
    except safe_io.InputError as e:
        p.error(f"--nimbus {e}{' (cargo build --release)' if e.missing else ''}")
    return a


def _die_with_parent():
    """Runs in the child before exec: a worker killed by the cluster takes nimbus with it, so
    the retry is not locked out of the part folder by an orphan."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def run_part(nimbus: str, datagen: list[str], k: int, n: int, out: str, threads: int) -> dict:
    """One part: `nimbus datagen ... --shard k/n --out out` (resumes what is already there)."""
    cmd = [nimbus, "datagen", *datagen, "--shard", f"{k}/{n}", "--out", out, "--quiet"]
    env = {**os.environ, "RAYON_NUM_THREADS": str(threads)}
    t0 = time.time()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True,
                       preexec_fn=_die_with_parent)
    if r.returncode != 0:
        raise RuntimeError(f"part {k}/{n}: `{shlex.join(cmd)}` exited with {r.returncode}: "
                           f"{(r.stderr or r.stdout).strip()[-2000:]}")
    return {"part": k, "seconds": time.time() - t0, "summary": r.stdout.strip(),
            "node": os.uname().nodename, "pid": os.getpid()}


def shards_written(part_dir: Path) -> int:
    return sum(1 for _ in part_dir.glob("*_meta.npy")) if part_dir.is_dir() else 0


def main(argv=None) -> int:
    a = parse_args(argv)
    import ray

    say = lambda *m: print(*m, flush=True)  # noqa: E731
    parts_dir = a.out / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    init = {"address": a.address} if a.address else {"num_cpus": a.num_cpus}
    ray.init(**init, include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=a.cpus_per_part, max_retries=a.retries,
                      retry_exceptions=True)(run_part)
    dirs = [parts_dir / str(k) for k in range(1, a.parts + 1)]
    t0 = time.time()
    pending = {task.remote(str(a.nimbus.resolve()), a.datagen, k, a.parts,
                           str(d.resolve()), a.cpus_per_part): k
               for k, d in zip(range(1, a.parts + 1), dirs)}
    say(f"{a.parts} parts on Ray ({ray.cluster_resources().get('CPU', 0):.0f} CPUs), "
        f"{a.retries} retries each -> {parts_dir}")
    done = []
    failed = None
    last = time.time()
    while pending:
        ready, _ = ray.wait(list(pending), timeout=1.0)
        for ref in ready:
            k = pending.pop(ref)
            try:
                r = ray.get(ref)
                done.append(r)
                say(f"part {k}/{a.parts} done in {r['seconds']:.1f} s on {r['node']} "
                    f"({len(done)} of {a.parts}): {r['summary']}")
            except Exception as e:  # noqa: BLE001 — reported, then the run stops
                failed = failed or f"part {k}/{a.parts} failed after {a.retries} retries: {e}"
                say(failed)
        if time.time() - last >= a.progress_every and pending:
            last = time.time()
            shards = sum(shards_written(d) for d in dirs)
            say(f"{time.time() - t0:.0f} s: {len(done)} of {a.parts} parts done, "
                f"{shards} shards written")
    ray.shutdown()
    if failed:
        say("not merged: finish the failed parts (run this command again: it resumes)")
        return 1
    merge = [str(a.nimbus), "datagen", "merge", *map(str, dirs), "--out", str(a.out)]
    r = subprocess.run(merge, capture_output=True, text=True)
    if r.returncode != 0:
        say(f"merge failed: {r.stderr.strip() or r.stdout.strip()}")
        return 1
    say(r.stdout.strip())
    say(f"{time.time() - t0:.1f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
