"""Synthetic record sets in the `nimbus datagen` layout, for the tests and for the training
throughput benchmark (`bench/train_throughput.py`): the network's cost does not depend on the
values, and the tests need a smooth target the network can learn."""

import hashlib
import json
from pathlib import Path

import numpy as np

from .model import DESCRIPTOR_LEN


def synthetic_target(x: np.ndarray) -> np.ndarray:
    """A smooth, positive 'radiance' of a descriptor: brighter for thin level-1 neighbourhoods
    and for small gamma (forward scattering), with a contribution from a coarse level."""
    gamma = x[:, -1]
    near = x[:, :225].mean(axis=1)
    far = x[:, 5 * 225 : 6 * 225].mean(axis=1)
    return (0.3 * np.exp(-near) * (1.2 + np.cos(gamma)) + 0.1 * far).astype(np.float32)


def write_set(root: Path, n_train: int, n_test: int, seed: int = 0, shard: int = 100,
              sha256: bool = False) -> Path:
    """A record set in the `nimbus datagen` layout with synthetic descriptors and targets.
    ``sha256``: the manifest lists each shard file's SHA-256 (field ``shards[i].sha256``, as
    `nimbus datagen` writes it)."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    shards = []
    for split, n in (("train", n_train), ("test", n_test)):
        for k, lo in enumerate(range(0, n, shard)):
            m = min(shard, n - lo)
            # Clouds are smooth: each level's 225 densities scatter little around a level mean.
            level = rng.gamma(2.0, 0.5, size=(m, 10, 1))
            x = np.empty((m, DESCRIPTOR_LEN), np.float32)
            x[:, :-1] = (level * rng.uniform(0.9, 1.1, size=(m, 10, 225))).reshape(m, -1)
            x[:, -1] = rng.uniform(0, np.pi, size=m)
            y = synthetic_target(x)
            names = {w: f"{split}_{k:05}_{w}.npy" for w in ("x", "y", "meta")}
            np.save(root / names["x"], x)
            np.save(root / names["y"], y)
            np.save(root / names["meta"], np.zeros((m, 13), np.float32))
            entry = {"split": split, "index": k, "records": m, "converged": m, **names}
            if sha256:
                entry["sha256"] = [hashlib.sha256((root / names[w]).read_bytes()).hexdigest()
                                   for w in ("x", "y", "meta")]
            shards.append(entry)
    manifest = {
        "format": "nimbus-rpnn-records/1",
        "descriptor_len": DESCRIPTOR_LEN,
        "settings": {"phase": "hg", "albedo": 1.0, "seed": seed, "max_samples": 0},
        "clouds": [{"name": "a", "split": "train"}, {"name": "b", "split": "test"}],
        "shards": shards,
        "records": n_train + n_test,
        "converged": n_train + n_test,
        "convergence_rate": 1.0,
    }
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root
