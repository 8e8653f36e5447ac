#!/usr/bin/env python3
"""Writes the ONNX test fixtures of `nimbus-rpnn` (crates/rpnn/tests/data/):

- rpnn-tiny.onnx: an RPNN (10 levels, width 16, 3 head layers, 1 output) with random weights;
- rpnn-tiny-io.npy: float32 [16, 2252], 16 random descriptors with torch's output appended;
- rpnn-micro.onnx, rpnn-micro-io.npy: the same architecture at its smallest (2 levels of 3
  points, width 2, 1 head layer; ≈ 2 kB), so the reader is tested on another shape and the
  `onnx` fuzz target mutates a whole valid model quickly;
- not-rpnn.onnx: a vanilla MLP on the whole descriptor (the reader must refuse it);
- rpnn-tiny-sky.onnx, rpnn-tiny-sky-io.npy: rpnn-tiny with a sky head (`train_sky.py`'s
  architecture: 2 ReLU layers of 16 and 25 linear outputs), its output [n, 1 + 25];

    training/.venv/bin/python training/make_fixtures.py
"""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rpnn import export  # noqa: E402
from rpnn.model import DESCRIPTOR_LEN, RPNN  # noqa: E402

out = Path(__file__).resolve().parents[1] / "crates/rpnn/tests/data"
out.mkdir(parents=True, exist_ok=True)
torch.manual_seed(42)
m = RPNN(width=16).eval()
with torch.no_grad():
    for p in m.parameters():
        p.uniform_(-0.3, 0.3)  # wide enough that no ReLU is dead for every input
export.export_onnx(m, out / "rpnn-tiny.onnx", {"nimbus.rpnn.phase": "hg"})
rng = np.random.default_rng(7)
x = rng.gamma(1.5, 0.6, size=(16, DESCRIPTOR_LEN)).astype(np.float32)
x[:, -1] = rng.uniform(0, np.pi, size=16)
with torch.no_grad():
    y = m(torch.from_numpy(x)).numpy()
np.save(out / "rpnn-tiny-io.npy", np.concatenate([x, y], axis=1))

torch.manual_seed(43)
micro = RPNN(levels=2, points=3, width=2, head_layers=1).eval()
with torch.no_grad():
    for p in micro.parameters():
        p.uniform_(-0.8, 0.8)
    micro.head[-1].bias.fill_(1.0)  # a live output (the last ReLU is dead at random weights)
export.export_onnx(micro, out / "rpnn-micro.onnx", {"nimbus.rpnn.phase": "hg"})
xm = rng.gamma(1.5, 0.6, size=(8, micro.input_len)).astype(np.float32)
with torch.no_grad():
    ym = micro(torch.from_numpy(xm)).numpy()
np.save(out / "rpnn-micro-io.npy", np.concatenate([xm, ym], axis=1))


class Vanilla(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.a = torch.nn.Linear(DESCRIPTOR_LEN, 16)
        self.b = torch.nn.Linear(16, 1)

    def forward(self, x):
        return torch.relu(self.b(torch.relu(self.a(x))))


v = Vanilla().eval()
v.input_len = DESCRIPTOR_LEN
v.config = lambda: {"kind": "vanilla"}
export.export_onnx(v, out / "not-rpnn.onnx")

from train_sky import SkyHead, SkyRPNN  # noqa: E402

torch.manual_seed(44)
sky = SkyRPNN(m, SkyHead(16, 3)).eval()
with torch.no_grad():
    for p in sky.head.parameters():
        p.uniform_(-0.3, 0.3)
export.export_onnx(sky, out / "rpnn-tiny-sky.onnx", {"nimbus.rpnn.phase": "hg", "nimbus.rpnn.sky": "sh4"})
with torch.no_grad():
    ys = sky(torch.from_numpy(x)).numpy()
np.save(out / "rpnn-tiny-sky-io.npy", np.concatenate([x, ys], axis=1))

# A sky head that reads block 4's output beside the last block's (train_sky.py --sky-blocks
# 4,9): its first layer reads 32 values.
torch.manual_seed(45)
sky2 = SkyRPNN(m, SkyHead(32, 3, hidden=16), blocks=[4, 9]).eval()
with torch.no_grad():
    for p in sky2.head.parameters():
        p.uniform_(-0.3, 0.3)
export.export_onnx(sky2, out / "rpnn-tiny-sky2.onnx",
                   {"nimbus.rpnn.phase": "hg", "nimbus.rpnn.sky": "sh4"})
with torch.no_grad():
    ys2 = sky2(torch.from_numpy(x)).numpy()
np.save(out / "rpnn-tiny-sky2-io.npy", np.concatenate([x, ys2], axis=1))
print(f"wrote fixtures to {out}")
