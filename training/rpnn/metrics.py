"""Per-record errors of a model on a precise split, and the noise of the split's labels (the
figures of the model card; used by train.py and evaluate.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from . import data as rdata

GAMMA_BINS_DEG = [0, 30, 60, 90, 120, 150, 180]


def record_errors(model, batches, batch: int, kinds: np.ndarray | None = None) -> dict | None:
    """Per-record relative error |y_hat - y| / y on a precise split: median overall, by gamma
    (30-degree bins; gamma = 180 is front-lit) and by target size (terciles), plus the ratio of
    mean prediction to mean target (overall and per gamma bin, with the standard error of the
    per-bin ratio: the bias an image lit at that angle inherits). `batches`: a train.Batches;
    `kinds`: the cloud kind of each of its records in order (`data.cloud_kinds`), which adds the
    median and mean ratio per kind. None when it is empty or holds no record with a positive
    target."""
    if len(batches) == 0:
        return None
    model.eval()
    preds, ys, gammas = [], [], []
    with torch.no_grad():
        for x, y in batches.iterate(batch, None):
            preds.append(model(x)[:, 0].cpu().numpy())
            ys.append(y.cpu().numpy())
            gammas.append(x[:, -1].cpu().numpy())
    p, y, g = np.concatenate(preds), np.concatenate(ys), np.degrees(np.concatenate(gammas))
    ok = y > 0
    if not ok.any():
        return None  # no record with a positive target: relative errors are undefined
    if kinds is not None and len(kinds) != len(y):
        raise ValueError(f"{len(kinds)} cloud kinds for {len(y)} records")
    pk, yk, g = p[ok], y[ok], g[ok]
    rel = np.abs(pk - yk) / yk
    out = {"records": int(ok.sum()), "median_rel_error": float(np.median(rel)),
           "mean_ratio": float(pk.mean() / yk.mean()), "by_gamma": [], "by_target": []}
    for lo, hi in zip(GAMMA_BINS_DEG[:-1], GAMMA_BINS_DEG[1:]):
        sel = (g >= lo) & ((g < hi) | (hi == 180))
        if sel.any():
            n, ym = int(sel.sum()), float(yk[sel].mean())
            out["by_gamma"].append({"gamma_deg": [lo, hi], "records": n,
                                    "median_rel_error": float(np.median(rel[sel])),
                                    "mean_ratio": float(pk[sel].mean()) / ym,
                                    "mean_ratio_se": float((pk[sel] - yk[sel]).std()
                                                           / np.sqrt(n) / ym)})
    edges = np.quantile(yk, [0, 1 / 3, 2 / 3, 1])
    for i in range(3):
        sel = (yk >= edges[i]) & ((yk < edges[i + 1]) | (i == 2))
        if sel.any():
            out["by_target"].append({"target": [float(edges[i]), float(edges[i + 1])],
                                     "records": int(sel.sum()),
                                     "median_rel_error": float(np.median(rel[sel]))})
    if kinds is not None:
        kk = np.asarray(kinds, dtype=object)[ok]
        out["by_kind"] = []
        for k in sorted(set(kk.tolist())):
            sel = kk == k
            out["by_kind"].append({"kind": str(k), "records": int(sel.sum()),
                                   "median_rel_error": float(np.median(rel[sel])),
                                   "mean_ratio": float(pk[sel].mean() / yk[sel].mean())})
    return out


def with_label_noise(err: dict | None, root: Path | list[Path], split: str) -> dict | None:
    """Adds to a split's record errors the median relative noise of its labels and the
    median error a perfect model would show against them (|N(0, s_i)| per record, simulated
    with a fixed seed); the errors themselves are never corrected for it."""
    if not err:
        return err
    roots = root if isinstance(root, list) else [root]
    s = np.concatenate([rdata.label_noise(r, split) for r in roots])
    s = s[np.isfinite(s)]
    rng = np.random.default_rng(0)
    err["label_noise_median"] = float(np.median(s)) if s.size else None
    err["noise_floor_median"] = float(np.median(np.abs(rng.normal(0.0, s)))) if s.size else None
    return err
