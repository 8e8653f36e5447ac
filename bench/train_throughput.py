#!/usr/bin/env python3
"""Training throughput of `training/train.py`: records per second of an epoch, counted as the
model cards count it (training rows / epoch wall time, the epoch's validation included).

    python3 bench/train_throughput.py [--records N] [--epochs E] [--batch B] [--device D]

The records are synthetic descriptors in the `nimbus datagen` layout (the network's cost does
not depend on their values); validation takes 2 % of them, as a held-out set of a real run is
small against its training set. The first epoch (allocation, CUDA start-up) is left out when
there are more. Prints a line per batch size: `<records/s> <device> <training rows> <batch>`.
"""

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path

root = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(root / "training"))

from rpnn.data import split_indices  # noqa: E402
from rpnn.synthetic import write_set  # noqa: E402

VAL_FRACTION = 0.02


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--records", type=int, default=200_000)
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--batch", type=int, nargs="+", default=[1000],
                   help="minibatch sizes, each measured on the same records (§5.2: 1000)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    a = p.parse_args()
    if a.records < 100 or a.epochs < 1 or min(a.batch) < 1:
        p.error("--records must be >= 100, --epochs and --batch >= 1")
    with tempfile.TemporaryDirectory() as tmp:
        data = write_set(Path(tmp) / "data", a.records, 200, shard=20_000)
        fit = len(split_indices(a.records, VAL_FRACTION, 0)[0])
        import torch

        dev = a.device if a.device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
        for batch in a.batch:
            run = Path(tmp) / f"run{batch}"
            subprocess.run([sys.executable, str(root / "training" / "train.py"), "--data",
                            str(data), "--run", str(run), "--epochs", str(a.epochs), "--batch",
                            str(batch), "--device", a.device, "--val-fraction",
                            str(VAL_FRACTION), "--quiet", "--no-check"], check=True)
            with open(run / "log.csv") as f:
                t = [float(r["seconds"]) for r in csv.DictReader(f)]
            # t[0] is epoch 0 (the untrained network's losses, no training); t[i] cumulative.
            dt = [b - a_ for a_, b in zip(t[1:-1], t[2:])] if len(t) > 2 else [t[1]]
            print(f"{fit * len(dt) / sum(dt):.0f} {dev} {fit} {batch}", flush=True)


if __name__ == "__main__":
    main()
