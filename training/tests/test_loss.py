"""The losses under label noise: fixed-count Monte Carlo labels are unbiased but heavy-tailed
(a path-traced L_i sample has a relative standard deviation of about 5 under HG g = 0.857 and a
delta sun). A loss whose minimiser is the conditional mean learns the truth from them; the
paper's log loss learns something smaller (Jensen)."""

import numpy as np
import torch
from torch import nn

from rpnn.model import LOSSES, axis_turns, mirror_columns, quarter_turn_columns, rel_l2_loss


def noisy_labels(truth: np.ndarray, samples: np.ndarray, rng) -> np.ndarray:
    """Means of `samples` lognormal draws with mean `truth` and relative sd 5 per draw."""
    s2 = np.log(1.0 + 25.0)  # lognormal: relative variance exp(s^2) - 1 = 25
    out = np.empty_like(truth)
    for n in np.unique(samples):
        sel = samples == n
        draws = rng.lognormal(-0.5 * s2, np.sqrt(s2), size=(sel.sum(), n))
        out[sel] = truth[sel] * draws.mean(axis=1)
    return out


def fit(loss_name: str, seed: int = 0) -> tuple[float, float, float]:
    """Trains a small MLP on noisy labels of t(x) = 0.2 + 2 x^2 (x in [0, 1]; targets 0.2 ... 2.2,
    the range of L_i per unit irradiance) and returns (mean prediction, mean truth, mean of the
    log loss's own minimiser exp(E[log(1 + y) | x]) - 1) on a grid."""
    rng = np.random.default_rng(seed)
    n = 20_000
    x = rng.uniform(0, 1, n).astype(np.float32)
    truth = (0.2 + 2.0 * x**2).astype(np.float32)
    samples = rng.choice([64, 128, 256], size=n)
    y = noisy_labels(truth, samples, rng).astype(np.float32)
    torch.manual_seed(seed)
    model = nn.Sequential(nn.Linear(1, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(),
                          nn.Linear(32, 1))
    with torch.no_grad():
        model[-1].bias.fill_(float(y.mean()))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    loss_fn = LOSSES[loss_name]
    xt, yt = torch.from_numpy(x)[:, None], torch.from_numpy(y)[:, None]
    steps = 1500
    g = torch.Generator().manual_seed(seed)
    for step in range(steps):
        # Cosine decay to 0: the last steps average the label noise instead of following it.
        for gr in opt.param_groups:
            gr["lr"] = 3e-3 * 0.5 * (1 + np.cos(np.pi * step / steps))
        idx = torch.randint(0, n, (1000,), generator=g)
        opt.zero_grad()
        loss_fn(model(xt[idx]), yt[idx]).backward()
        opt.step()
    grid = torch.linspace(0, 1, 1001)[:, None]
    with torch.no_grad():
        pred = model(grid)[:, 0].numpy()
    # The log loss's minimiser per x, estimated in 20 bins of x from the labels themselves.
    bins = np.minimum((x * 20).astype(int), 19)
    log_min = np.mean([np.expm1(np.log1p(y[bins == b]).mean()) for b in range(20)])
    return float(pred.mean()), float((0.2 + 2.0 * grid[:, 0].numpy() ** 2).mean()), float(log_min)


def test_relative_l2_learns_the_mean_from_heavy_tailed_labels():
    pred, truth, _ = fit("rel-l2")
    # Labels have a relative sd of 5/sqrt(64..256) = 0.31 ... 0.63; 20 000 of them pin the mean
    # to ~0.4 % (more: the lognormal tail), and the network's fit adds a little: bound 2 %.
    assert abs(pred / truth - 1) < 0.02, (pred, truth)


def test_log_loss_is_biased_low_under_the_same_noise():
    pred, truth, log_min = fit("log")
    # The log loss converges to exp(E[log(1 + y) | x]) - 1 < E[y | x] (Jensen): for these labels
    # ≈ 4 % low (seen: 3.8 %). The network lands on that minimiser (within 1.5 %), not on the
    # truth: at least 2.5 % low, outside the unbiased loss's band above.
    assert log_min / truth < 0.975, (log_min, truth)
    assert abs(pred / log_min - 1) < 0.015, (pred, log_min)
    assert pred / truth < 0.975, (pred, truth)


def test_rel_l2_gradient_does_not_flow_through_the_denominator():
    pred = torch.tensor([2.0], requires_grad=True)
    rel_l2_loss(pred, torch.tensor([1.0])).backward()
    # d/dp (p - 1)^2 / sg(p + 0.01)^2 = 2 (p - 1) / (p + 0.01)^2 at p = 2.
    assert torch.allclose(pred.grad, torch.tensor([2.0 / 2.01**2]))


def test_mirror_is_an_involution_that_flips_x_only():
    m = mirror_columns()
    assert torch.equal(m[m], torch.arange(2251))
    # Level 3, point (ix, iy, iz) = (1, 2, 4) -> (3, 2, 4); gamma stays.
    p = 1 + 5 * 2 + 25 * 4
    assert m[2 * 225 + p] == 2 * 225 + 3 + 5 * 2 + 25 * 4
    assert m[2250] == 2250
    # The plane ix = 2 is fixed.
    assert m[2 + 5 * 3 + 25 * 7] == 2 + 5 * 3 + 25 * 7


def test_quarter_turn_is_exact_and_of_order_four():
    t = quarter_turn_columns()
    ident = torch.arange(2251)
    assert not torch.equal(t, ident)
    assert torch.equal(t[t[t[t]]], ident)
    # Two turns are the half turn (ix, iy) -> (4 - ix, 4 - iy); gamma stays.
    p = 1 + 5 * 3 + 25 * 6
    assert t[t][4 * 225 + p] == 4 * 225 + 3 + 5 * 1 + 25 * 6
    assert t[2250] == 2250
    # The new point (ix, iy) reads the old (4 - iy, ix): the new x axis is the old y.
    assert t[0 * 225 + 1 + 5 * 0 + 25 * 2] == 4 + 5 * 1 + 25 * 2
    # The stencil's axis column (ix = iy = 2) is fixed.
    for iz in range(9):
        assert t[7 * 225 + 2 + 10 + 25 * iz] == 7 * 225 + 2 + 10 + 25 * iz


def test_axis_turns_touch_only_rows_near_the_axis():
    g = torch.Generator().manual_seed(0)
    x = torch.rand((8, 2251), generator=g)
    x[:, -1] = torch.tensor([0.01, 0.5, 1.5, 3.13, 3.0, 0.0, np.pi, 0.06])
    t = quarter_turn_columns()
    q = torch.tensor([1, 1, 2, 3, 1, 0, 2, 1])
    y = axis_turns(x, np.radians(3.0), t, q)
    # 3° = 0.0524 rad: rows 0, 3, 5, 6 are near the axis; 1, 2, 4, 7 are not.
    for r in (1, 2, 4, 7):
        assert torch.equal(y[r], x[r])
    assert torch.equal(y[0], x[0][t])
    assert torch.equal(y[3], x[3][t[t[t]]])
    assert torch.equal(y[5], x[5])  # q = 0
    assert torch.equal(y[6], x[6][t[t]])
    assert torch.equal(y[:, -1], x[:, -1])
