#!/usr/bin/env python3
"""A Python call against the CLI's whole process: `nimbus.render` of a scene file (scene load
included, the module's import not) against `nimbus render FILE` as a subprocess (its start,
scene load, render and EXR write), and `nimbus.datagen` (in memory, and to shards) against
`nimbus datagen` — same settings and seed, runs interleaved, the best of --repeat.

  training/.venv/bin/python bench/python_vs_cli.py --scene scenes/demo-cumulus.toml --spp 64
"""
import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import nimbus

ROOT = Path(__file__).resolve().parents[1]
CLI = ROOT / "target" / "release" / "nimbus"


def timed(f):
    t0 = time.perf_counter()
    f()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "demo-cumulus.toml"))
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--rpnn-spp", type=int, default=16)
    ap.add_argument("--records", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    rows = []
    for method, spp in [("pt", a.spp), ("rpnn", a.rpnn_spp)]:
        extra = ["--backend", "ort"] if method == "rpnn" else []
        cli, py = [], []
        for _ in range(a.repeat):
            cli.append(timed(lambda: subprocess.run(
                [str(CLI), "render", a.scene, "--method", method, "--spp", str(spp), "--seed",
                 "1", "-q", "-o", str(tmp / "cli.exr"), *extra], check=True,
                capture_output=True)))
            settings = {"backend": "ort"} if method == "rpnn" else {}
            py.append(timed(lambda: nimbus.render(nimbus.Scene.load(a.scene), method, spp=spp,
                                                  seed=1, **settings)))
        rows.append({"what": f"render {method} {spp} spp", "cli_s": min(cli), "python_s": min(py)})
        print(json.dumps(rows[-1]), flush=True)
    flags = dict(clouds="gen:8", test_records=0, val_records=0, samples=256, shard_size=64,
                 seed=1, device="cpu")
    cli, mem, shards = [], [], []
    for i in range(a.repeat):
        cli.append(timed(lambda: subprocess.run(
            [str(CLI), "datagen", "--records", str(a.records), "--clouds", "gen:8",
             "--test-records", "0", "--val-records", "0", "--samples", "256", "--shard-size",
             "64", "--seed", "1", "--device", "cpu", "-q", "-o", str(tmp / f"cli{i}")],
            check=True, capture_output=True)))
        mem.append(timed(lambda: nimbus.datagen(a.records, **flags)))
        shards.append(timed(lambda: nimbus.datagen(a.records, out=tmp / f"py{i}", **flags)))
    rows.append({"what": f"datagen {a.records} records (records/s)",
                 "cli": a.records / min(cli), "python_memory": a.records / min(mem),
                 "python_shards": a.records / min(shards)})
    print(json.dumps(rows[-1]), flush=True)


if __name__ == "__main__":
    main()
