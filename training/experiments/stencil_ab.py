"""A/B of the stencil's scale on one kind of cloud (BENCHMARKS.md, "One million mixed records").

Kallweit 2017 §4.2 ties the stencil to the cloud's mean free path: level k steps
0.5 · 2^(k−1) mean free paths. This experiment retrains the paper's network from scratch on the
same records and labels with the stencil scaled by S (S = 1: the paper's), and scores both on
the same held-out records, so the only difference is the descriptor.

    python training/experiments/stencil_ab.py prep --train out/cirrus-data \
        --test out/stage-d/seed4-test-precise ... --kind cirrus --work /tmp/ab
    for s in 1 0.25; do
      for n in train t0 t1 t2 t3; do   # the sets prep wrote, in the order given
        cargo run --release -p nimbus-rpnn --example stencil_scale -- \
          /tmp/ab/${n}_clouds.json /tmp/ab/$n.cfg $s /tmp/ab/${n}_s$s.f32
      done
      python training/experiments/stencil_ab.py train --work /tmp/ab --scale $s --epochs 5
    done
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rpnn.model import RPNN, rel_l2_loss  # noqa: E402

COLUMNS = ["cloud", "x", "y", "z", "view_x", "view_y", "view_z", "light_x", "light_y", "light_z"]


def prep(args):
    """Writes each set's configurations of `--kind` (N × 10 float32), labels and clouds."""
    sets = [("train", args.train, "train")]
    sets += [(f"t{i}", p, "test") for i, p in enumerate(args.test)]
    for name, root, split in sets:
        if not (root / "manifest.json").is_file():
            raise SystemExit(f"{root}: no manifest.json (not a record set)")
        man = json.loads((root / "manifest.json").read_text())
        cols = man["meta_columns"]
        shards = [s for s in man["shards"] if s["split"] == split]
        meta = np.concatenate([np.load(root / s["meta"]) for s in shards])
        y = np.concatenate([np.load(root / s["y"]).reshape(-1) for s in shards])
        keep = np.array([man["clouds"][int(c)].get("kind") == args.kind for c in meta[:, 0]])
        idx = [cols.index(c) for c in COLUMNS]
        meta[keep][:, idx].astype("<f4").tofile(args.work / f"{name}.cfg")
        np.save(args.work / f"{name}_y.npy", y[keep])
        (args.work / f"{name}_clouds.json").write_text(json.dumps(man["clouds"]))
        print(f"{name}: {keep.sum()} {args.kind} records of {len(y)}")


def train(args):
    """The paper's network from scratch: rel-l2, Adam 1e-3 cosine, batch 1 000, mirroring."""
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    s = args.scale
    need = [args.work / f"train_s{s}.f32", args.work / "train_y.npy"]
    missing = [str(p) for p in need if not p.is_file()]
    if missing:
        raise SystemExit(f"missing {', '.join(missing)}: run prep and the stencil_scale example "
                         "first (see the docstring)")
    load = lambda n: torch.from_numpy(  # noqa: E731
        np.fromfile(args.work / f"{n}_s{s}.f32", dtype="<f4").reshape(-1, 2251))
    x_all, y_all = load("train"), torch.from_numpy(np.load(args.work / "train_y.npy"))
    tests = {p.name[:-4]: (load(p.name[:-4]), np.load(args.work / f"{p.name[:-4]}_y.npy"))
             for p in sorted(args.work.glob("t[0-9]*.cfg"))}
    perm = np.arange(2250).reshape(10, 9, 5, 5)[:, :, :, ::-1].reshape(-1)
    mirror = torch.from_numpy(np.concatenate([perm, [2250]]))
    model = RPNN()
    model.init_output_bias(float(y_all.mean()))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    n, batch = len(y_all), 1000
    steps, step, t0 = args.epochs * (n // batch), 0, time.time()
    for epoch in range(args.epochs):
        order, total = torch.from_numpy(rng.permutation(n)), 0.0
        for i in range(n // batch):
            idx = order[i * batch:(i + 1) * batch]
            x, y = x_all[idx], y_all[idx].float()
            flip = torch.rand(batch) < 0.5
            x[flip] = x[flip][:, mirror]
            for g in opt.param_groups:
                g["lr"] = 1e-3 * 0.5 * (1 + math.cos(math.pi * step / steps))
            loss = rel_l2_loss(model(x).reshape(-1), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total, step = total + loss.item(), step + 1
        with torch.no_grad():
            errs = {k: np.abs(model(x).reshape(-1).numpy() - y) / y for k, (x, y) in tests.items()}
        med = 100 * np.median(np.concatenate(list(errs.values())))
        per = " ".join(f"{k} {100 * np.median(v):.1f} %" for k, v in errs.items())
        print(f"scale {s} epoch {epoch + 1}: train loss {total / (n // batch):.4f}, "
              f"test median {med:.1f} % ({per}), {time.time() - t0:.0f} s", flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("prep")
    a.add_argument("--train", type=Path, required=True)
    a.add_argument("--test", type=Path, nargs="+", required=True)
    a.add_argument("--kind", default="cirrus")
    a.add_argument("--work", type=Path, required=True)
    b = sub.add_parser("train")
    b.add_argument("--work", type=Path, required=True)
    b.add_argument("--scale", required=True, help="as given to stencil_scale (names the files)")
    b.add_argument("--epochs", type=int, default=5)
    b.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    prep(args) if args.cmd == "prep" else train(args)


if __name__ == "__main__":
    main()
