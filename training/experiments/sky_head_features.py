"""Does the sky head gain from more of the frozen trunk than its last block's output?
(docs/experiments/2026-12-07-sky-head-size.md, "More of the trunk").

Trains ``train_sky.py``'s head, with the same loss, optimiser and schedule, on the
concatenated outputs of the chosen residual blocks (0-based; the shipped head reads block 9,
the last) of the frozen sun model, and prints the errors on a test set as ``train_sky.py``
does. A study only: the renderer's sky head reads the last block.

    python training/experiments/sky_head_features.py --init models/rpnn-hg.onnx \
        --data out/sky_set --test-data out/sky_test --blocks 4,9
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import train_sky as ts  # noqa: E402
from rpnn import export as rexport  # noqa: E402
from rpnn.model import RPNN  # noqa: E402


def block_features(sun: RPNN, x: np.ndarray, blocks: list[int], batch: int = 4096) -> torch.Tensor:
    """The chosen blocks' outputs, concatenated, for every row."""
    out = []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            xb = torch.from_numpy(x[i:i + batch])
            o, keep = None, []
            for k, block in enumerate(sun.blocks):
                o = block(sun.level_input(xb, k), o)
                if k in blocks:
                    keep.append(o)
            out.append(torch.cat(keep, dim=1))
    return torch.cat(out)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--init", required=True, type=Path)
    p.add_argument("--data", required=True, type=Path)
    p.add_argument("--test-data", required=True, type=Path)
    p.add_argument("--blocks", default="9", help="comma-separated block indices (0-based)")
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--batch", type=int, default=1000)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    blocks = sorted({int(b) for b in args.blocks.split(",")})
    torch.manual_seed(args.seed)
    t0 = time.time()
    sun = RPNN(**ts.sun_config(args.init))
    rexport.import_onnx(sun, args.init)
    sun.eval()
    if not all(0 <= b < len(sun.blocks) for b in blocks):
        raise SystemExit(f"--blocks {args.blocks}: the model has blocks 0..{len(sun.blocks) - 1}")
    x, t = ts.load_set(args.data, "train")
    xv, tv = ts.load_set(args.data, "val")
    xt, tt = ts.load_set(args.test_data, "test")
    f, fv, ft = (block_features(sun, a, blocks) for a in (x, xv, xt))
    t, tv = torch.from_numpy(t), torch.from_numpy(tv)
    head = ts.SkyHead(f.shape[1], 3, hidden=sun.width)
    with torch.no_grad():
        head.layers[-1].bias.copy_(t.mean(dim=0))
        head.layers[-1].weight.mul_(0.1)
    opt = torch.optim.Adam(head.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=args.epochs)
    best, best_state = float("inf"), None
    for _ in range(args.epochs):
        head.train()
        order = torch.randperm(len(f))
        for i in range(0, len(f), args.batch):
            idx = order[i:i + args.batch]
            loss = ts.loss_fn(head(f[idx]), t[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
        head.eval()
        with torch.no_grad():
            val = float(ts.loss_fn(head(fv), tv))
        if val < best:
            best, best_state = val, {k: v.clone() for k, v in head.state_dict().items()}
    head.load_state_dict(best_state)
    head.eval()
    with torch.no_grad():
        test = ts.relative_errors(head(ft).numpy(), tt)
    r = {"blocks": blocks, "features": int(f.shape[1]), "val_loss": best, "test": test,
         "seconds": time.time() - t0}
    print(json.dumps(r), flush=True)
    return r


if __name__ == "__main__":
    main()
