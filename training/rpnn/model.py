"""The radiance-predicting network of Kallweit et al. 2017, §4.3 (Fig. 6).

For k = 1..K a block reads stencil level k and the angle gamma, z_k = (Sigma^k, gamma), and the
previous block's output o_{k-1} (o_0 = 0, so block 1 has no W1 term):

    F1 = ReLU(V z_k + W1 o_{k-1} + b1)
    F2 = W2 F1 + b2
    o_k = ReLU(F2 + o_{k-1})

followed by ``head_layers`` fully connected ReLU layers, the last of which produces the output
(o^M = f(W o^{M-1} + b), §4.3). With K = 10, width 200 and 3 head layers the network has 23 layers
and about 1.3 million parameters (the paper: "about 1.4 million").

Input layout (the contract with ``nimbus datagen``, crates/rpnn/src/descriptor.rs): one row of
2251 float32, level-major, ``x[(k-1)*225 + p]`` = density of stencil point p of level k (relative
to the cloud's mean extinction), ``x[2250]`` = gamma in radians. No other normalisation is applied:
the ONNX graph takes this row as it is and returns the indirect in-scattered radiance per unit
sun irradiance.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

LEVELS = 10
POINTS = 225
DESCRIPTOR_LEN = LEVELS * POINTS + 1


class Block(nn.Module):
    """One residual block of §4.3 (two fully connected layers and a skip connection)."""

    def __init__(self, level_inputs: int, width: int, first: bool):
        super().__init__()
        self.V = nn.Linear(level_inputs, width, bias=True)  # V z_k + b1
        # o_0 = 0: the first block has no previous output to read.
        self.W1 = None if first else nn.Linear(width, width, bias=False)
        self.W2 = nn.Linear(width, width, bias=True)  # W2 F1 + b2

    def forward(self, z: torch.Tensor, prev: torch.Tensor | None) -> torch.Tensor:
        a = self.V(z)
        if self.W1 is not None and prev is not None:
            a = a + self.W1(prev)
        f1 = torch.relu(a)
        f2 = self.W2(f1)
        return torch.relu(f2 if prev is None else f2 + prev)


class RPNN(nn.Module):
    """Progressive-feeding residual MLP (Kallweit 2017 §4.3)."""

    def __init__(
        self,
        levels: int = LEVELS,
        points: int = POINTS,
        width: int = 200,
        head_layers: int = 3,
        outputs: int = 1,
    ):
        super().__init__()
        if min(levels, points, width, head_layers, outputs) < 1:
            raise ValueError("levels, points, width, head_layers and outputs must be >= 1")
        self.levels, self.points, self.width = levels, points, width
        self.head_layers, self.outputs = head_layers, outputs
        self.blocks = nn.ModuleList(Block(points + 1, width, k == 0) for k in range(levels))
        dims = [width] * head_layers + [outputs]
        self.head = nn.ModuleList(nn.Linear(dims[i], dims[i + 1]) for i in range(head_layers))

    def init_output_bias(self, value: float) -> None:
        """Starts the output layer's bias at ``value`` (the mean training target).

        The last layer is a ReLU (§4.3); if its pre-activation starts negative for every input
        the gradient is zero and training never starts. Starting from the mean target puts the
        initial prediction where the loss is smallest for a constant and keeps it alive.
        """
        with torch.no_grad():
            self.head[-1].bias.fill_(float(value))

    @property
    def input_len(self) -> int:
        return self.levels * self.points + 1

    def config(self) -> dict:
        return {
            "levels": self.levels,
            "points": self.points,
            "width": self.width,
            "head_layers": self.head_layers,
            "outputs": self.outputs,
        }

    def level_input(self, x: torch.Tensor, k: int) -> torch.Tensor:
        """z_k = (Sigma^k, gamma) for block k (0-based)."""
        p = self.points
        gamma = x[:, self.levels * p :]
        return torch.cat([x[:, k * p : (k + 1) * p], gamma], dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        o = None
        for k, block in enumerate(self.blocks):
            o = block(self.level_input(x, k), o)
        for layer in self.head:
            o = torch.relu(layer(o))
        return o


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def log_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Kallweit 2017 Eq. (2): mean of (log(1 + y_hat) - log(1 + y))^2."""
    return torch.mean((torch.log1p(pred) - torch.log1p(target)) ** 2)


def rel_l2_loss(pred: torch.Tensor, target: torch.Tensor, eps: float = 0.01) -> torch.Tensor:
    """Relative L2 of Neural Radiance Caching (Müller et al. 2021, §5):
    mean((y_hat - y)^2 / (sg(|y_hat|) + eps)^2), sg = stop-gradient.

    The denominator does not depend on the label, so for any input the expected loss is
    minimised by y_hat = E[y | input]: zero-mean label noise (fixed-count Monte Carlo targets)
    averages out instead of biasing the network. Dividing by the prediction makes it relative in
    scale, so thin (small-target) configurations count as much as thick ones. ``eps`` (in units
    of the target, L_i per unit irradiance, mean ~ 1) keeps targets near 0 from dominating.
    """
    scale = pred.detach().abs() + eps
    return torch.mean(((pred - target) / scale) ** 2)


LOSSES = {"rel-l2": rel_l2_loss, "log": log_loss}


def quarter_turn_columns(levels: int = LEVELS, points: int = POINTS) -> torch.Tensor:
    """Column permutation of a descriptor row that turns the stencil's frame by 90 degrees about
    its z axis (the light direction): the new x axis is the old y, the new y the old -x, so the
    new point (ix, iy, iz) reads the old (4 - iy, ix, iz). The 5x5 grid maps onto itself, so the
    turn is exact; gamma is unchanged. Four turns are the identity.

    Where the view is parallel to the light (gamma = 0 or pi) the frame's x axis
    (z x view, crates/rpnn/src/descriptor.rs) is arbitrary, and every turn describes the same
    configuration; at an angle delta from that axis a turn describes the view direction turned
    by 90 degrees about the light, at most sqrt(2) sin(delta) radians away (used near the axis
    only: see ``axis_turns``).
    """
    if points != 225:
        raise ValueError("turning needs the 5x5x9 stencil (225 points)")
    idx = []
    for k in range(levels):
        for p in range(points):
            ix, iy, iz = p % 5, (p // 5) % 5, p // 25
            idx.append(k * points + (4 - iy) + 5 * ix + 25 * iz)
    idx.append(levels * points)
    return torch.tensor(idx, dtype=torch.long)


def axis_turns(x: torch.Tensor, band_rad: float, turn: torch.Tensor,
               q: torch.Tensor) -> torch.Tensor:
    """Turns the stencil of each row whose gamma (last column) lies within ``band_rad`` of 0 or
    pi by ``q`` (0-3, one per row) quarter turns about the light axis (``turn`` from
    ``quarter_turn_columns``): near the frame's singular direction the network sees the
    arbitrary azimuth of the frame in every orientation. Rows outside the band are unchanged.
    """
    g = x[:, -1]
    near = (g < band_rad) | (g > np.pi - band_rad)
    q = q.to(x.device)
    out = x
    for k in range(1, 4):
        out = torch.where((near & (q >= k))[:, None], out[:, turn], out)
    return out


def mirror_columns(levels: int = LEVELS, points: int = POINTS) -> torch.Tensor:
    """Column permutation of a descriptor row that mirrors the stencil across the plane of the
    view and light directions: ix -> 4 - ix (x is the frame's axis perpendicular to that plane,
    crates/rpnn/src/descriptor.rs). gamma is unchanged. L_i of the mirrored cloud at the mirrored
    point equals L_i of the original, so every record gives a second, free one.
    """
    if points != 225:
        raise ValueError("mirroring needs the 5x5x9 stencil (225 points)")
    idx = []
    for k in range(levels):
        for p in range(points):
            ix, rest = p % 5, p // 5
            idx.append(k * points + (4 - ix) + 5 * rest)
    idx.append(levels * points)
    return torch.tensor(idx, dtype=torch.long)
