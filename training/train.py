#!/usr/bin/env python3
"""Train the RPNN of Kallweit et al. 2017 (§4.3 network, §5.2 procedure) on `nimbus datagen`
records and export it to ONNX.

    python training/train.py --data out/rpnn-hg --run out/train-hg --epochs 200 \
        --export models/rpnn-hg.onnx

- Loss: ``--loss rel-l2`` (default) is the relative L2 of Neural Radiance Caching,
  (y_hat - y)^2 / (sg(|y_hat|) + 0.01)^2, whose minimiser is the conditional mean, so noisy
  fixed-count labels (``nimbus datagen --samples N``) teach the same function as converged ones;
  ``--loss log`` is the paper's (log(1 + y_hat) - log(1 + y))^2 (§5.2), biased low under label
  noise. Adam, minibatches of 1000 (§5.2); ``--schedule cosine`` decays the step size to 0 over
  the run (averages out label noise at the end), ``constant`` is the paper's.
- ``--ema DECAY``: an exponential moving average of the weights (Polyak averaging), updated
  after every step; it is what is validated, kept and exported. With noisy labels the iterates
  scatter about the minimiser and their average lies closer to it than any one of them. 0 (the
  default) is off, as the paper trains.
- ``--blend-init W`` (with ``--init``): exports (1 - W) x the starting weights + W x the trained
  ones, weight-space interpolation between a model and its fine-tuning (WiSE-FT, Wortsman et al.
  2022): a fine-tuning set that differs from the first one moves the network towards it, and
  the blend keeps part of what the first set taught. The card's per-record errors are the
  blend's.
- ``--mirror`` (default): each minibatch mirrors a random half of its rows across the plane of
  the view and light directions (stencil ix -> 4 - ix): a free second record.
- ``--axis-turns DEG``: rows within DEG degrees of gamma = 0 or 180 (view parallel to the light,
  where the frame's x axis is arbitrary) are turned by a random number of quarter turns about
  the light axis (exact on the stencil; the label is exact on the axis and approximate beside
  it, see ``rpnn.model.quarter_turn_columns``).
- Validation: the data set's "val" split (held-out clouds with precise labels) when it has one,
  else 25 % of the training records (fixed seed); the test clouds' records (split "test") are
  reported separately, with the per-record median relative error by gamma and target size.
- Every epoch: validation (and test) loss, a row in ``<run>/log.csv``, ``<run>/curves.png``,
  ``<run>/last.pt`` (resumable with ``--resume``) and ``<run>/best.pt`` when validation improves.
- ``--export`` writes the best checkpoint as ONNX, checks it against torch with onnxruntime on
  real records (max relative difference < 1e-5) and writes the model card next to it.
- Data-parallel: ``torchrun --nproc_per_node N training/train.py ...`` (``torch.distributed``
  DDP; gloo on CPU, NCCL on GPUs). The global minibatch (``--batch``), its order, the mirroring
  and the step-size schedule are those of the single-process run: every rank draws the same
  global permutation, takes every N-th row of each global minibatch (reading only those rows
  of the memory-mapped shards) and weighs its loss by its share, so the averaged gradient is the
  single process's. Validation and test losses are summed over the ranks; rank 0 alone logs,
  writes checkpoints (resumable as usual) and exports. See ``training/CLUSTER.md``.
"""

from __future__ import annotations

import argparse
import csv
import functools
import gc
import hashlib
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from rpnn import data as rdata  # noqa: E402
from rpnn import export as rexport  # noqa: E402
from rpnn import safe_io  # noqa: E402
from rpnn.metrics import record_errors, with_label_noise  # noqa: E402,F401
from rpnn.model import (  # noqa: E402
    LOSSES,
    RPNN,
    axis_turns,
    mirror_columns,
    parameter_count,
    quarter_turn_columns,
)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, type=Path, nargs="+",
                   help="`nimbus datagen --out` folders (several: their training and validation "
                        "splits together; the same phase function, albedo and light sampling)")
    p.add_argument("--run", "--run-dir", dest="run", required=True, type=Path,
                   help="folder for checkpoints, log and plot (write --run-dir under torchrun, "
                        "whose own option --run-path makes --run ambiguous)")
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--batch", type=int, default=1000, help="minibatch size (§5.2: 1000)")
    p.add_argument("--val-fraction", type=float, default=0.25)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    p.add_argument("--width", type=int, default=200)
    p.add_argument("--levels", type=int, default=10)
    p.add_argument("--head-layers", type=int, default=3)
    p.add_argument("--outputs", type=int, default=1, help="output channels (1: grey radiance)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam step size (default: Adam's own)")
    p.add_argument("--loss", default="rel-l2", choices=sorted(LOSSES),
                   help="rel-l2: unbiased under label noise (default); log: the paper's §5.2 loss")
    p.add_argument("--rel-eps", type=float, default=0.01, metavar="EPS",
                   help="rel-l2's floor in units of the target (0.01: Neural Radiance Caching's; "
                        "smaller weighs thin, small-target records closer to relatively)")
    p.add_argument("--init", type=Path, metavar="MODEL",
                   help="start from these weights (a .pt checkpoint of this script or an ONNX "
                        "file it exported) with a fresh optimiser and schedule: a fine-tuning "
                        "stage; ignored when --resume finds <run>/last.pt")
    p.add_argument("--mirror", action=argparse.BooleanOptionalAction, default=True,
                   help="mirror a random half of each minibatch (ix -> 4 - ix)")
    p.add_argument("--axis-turns", type=float, default=0.0, metavar="DEG",
                   help="quarter-turn the stencil about the light axis at random for records "
                        "within DEG degrees of gamma = 0 or 180, where the frame's azimuth is "
                        "arbitrary (0: off, as the shipped model was trained)")
    p.add_argument("--schedule", default="constant", choices=["constant", "cosine"],
                   help="step size over the epochs: constant (the paper) or cosine decay to 0")
    p.add_argument("--max-minutes", type=float, default=0.0,
                   help="stop after this much training time (0: no limit); the best checkpoint "
                        "is exported as usual")
    p.add_argument("--select", default="val", choices=["val", "last"],
                   help="the checkpoint kept as best.pt and exported: the lowest validation "
                        "loss (default) or the last epoch (with --schedule cosine the step size "
                        "has decayed to 0 there; a small validation set is noisier than that)")
    p.add_argument("--test-data", type=Path, metavar="DIR",
                   help="take the test records from this set's test split instead of --data's "
                        "(e.g. precise labels from `nimbus datagen --eval-noise`); its clouds "
                        "must be held out from --data's training clouds")
    p.add_argument("--ema", type=float, default=0.0, metavar="DECAY",
                   help="validate, keep and export an exponential moving average of the weights "
                        "with this decay per step (e.g. 0.999; 0: off)")
    p.add_argument("--blend-init", type=float, default=1.0, metavar="W",
                   help="export (1 - W) x the starting weights (--init) + W x the trained ones: "
                        "weight-space interpolation between a model and its fine-tuning "
                        "(WiSE-FT, Wortsman et al. 2022), which keeps what the starting weights "
                        "learnt of clouds the new set under-represents (1: the trained weights)")
    p.add_argument("--resume", action="store_true", help="continue from <run>/last.pt")
    p.add_argument("--preload", default="auto", choices=["auto", "yes", "no"],
                   help="copy the records into memory (GPU memory on CUDA) instead of reading "
                        "memory-mapped shards per batch; auto: when they take < 4 GiB")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    p.add_argument("--max-memory", metavar="SIZE",
                   help="memory budget (6G, 512M, bytes): no file larger is read, and records "
                        "are preloaded only within it (default: NIMBUS_MAX_MEMORY, else 3/4 of "
                        "the physical memory or of the cgroup's limit)")
    p.add_argument("--export", type=Path, help="write the best model as ONNX (+ card) here")
    p.add_argument("--reproduce", default="", help="the command recorded in the model card")
    p.add_argument("--check", action=argparse.BooleanOptionalAction, default=True,
                   help="read every training row once at the start to refuse non-finite values "
                        "(--no-check: trust the set, e.g. when resuming over a set larger than "
                        "the page cache)")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    for name in ("epochs", "batch", "width", "levels", "head_layers", "outputs"):
        v = getattr(args, name)
        if v < (0 if name == "epochs" else 1):
            p.error(f"--{name.replace('_', '-')} must be >= {0 if name == 'epochs' else 1}, got {v}")
    if not (args.lr > 0 and np.isfinite(args.lr)):
        p.error(f"--lr must be positive, got {args.lr}")
    if not 0.0 <= args.ema < 1.0:
        p.error(f"--ema must lie in [0, 1), got {args.ema}")
    if not (args.rel_eps > 0 and np.isfinite(args.rel_eps)):
        p.error(f"--rel-eps must be positive, got {args.rel_eps}")
    try:
        safe_io.set_budget(None if args.max_memory is None else
                           safe_io.parse_size(args.max_memory))
    except ValueError as e:
        p.error(f"--max-memory {e}")
    if args.init is not None:
        with safe_io.reporting_input_errors():
            try:
                safe_io.check_regular(args.init, what="a model (.pt checkpoint or .onnx file)")
            except safe_io.InputError as e:
                raise safe_io.InputError(f"--init {e}") from None
    if not 0.0 <= args.blend_init <= 1.0:
        p.error(f"--blend-init must lie in [0, 1], got {args.blend_init}")
    if args.threads < 0 or args.seed < 0:
        p.error(f"--threads and --seed must be >= 0, got {args.threads} and {args.seed}")
    if not (np.isfinite(args.max_minutes) and args.max_minutes >= 0):
        p.error(f"--max-minutes must be a finite number >= 0 (0: no limit), got {args.max_minutes}")
    if args.levels * 225 + 1 != rdata.DESCRIPTOR_LEN:
        p.error(f"--levels {args.levels}: the network would read {args.levels * 225 + 1} inputs, "
                f"the records hold {rdata.DESCRIPTOR_LEN} (10 levels of 5x5x9 densities and gamma)")
    if not 0.0 < args.val_fraction < 1.0:
        p.error(f"--val-fraction must lie in (0, 1), got {args.val_fraction}")
    seen = [os.path.realpath(d) for d in args.data]  # (a link loop: refused when read)
    if len(set(seen)) != len(seen):
        p.error("--data names a folder twice (its records would count twice)")
    return args


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: torch sees no CUDA device")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name, local_rank) if name == "cuda" else torch.device(name)


class Dist:
    """The process group of a ``torchrun`` launch (rank 0 of 1 without one)."""

    def __init__(self):
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        self.on = self.world > 1

    def start(self, device: torch.device) -> None:
        if self.on and not torch.distributed.is_initialized():
            backend = "nccl" if device.type == "cuda" else "gloo"
            if device.type == "cuda":
                torch.cuda.set_device(device)
            torch.distributed.init_process_group(backend=backend)

    def barrier(self) -> None:
        if self.on and torch.distributed.is_initialized():
            torch.distributed.barrier()

    def stop(self) -> None:
        if self.on and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()

    def sum(self, values: list[float], device) -> list[float]:
        """Element-wise sum over the ranks (float64)."""
        if not self.on:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=device)
        torch.distributed.all_reduce(t)
        return t.tolist()

    def max(self, value: float, device) -> float:
        if not self.on:
            return value
        t = torch.tensor([value], dtype=torch.float64, device=device)
        torch.distributed.all_reduce(t, op=torch.distributed.ReduceOp.MAX)
        return float(t.item())


class Batches:
    """Minibatches of a record subset; memory-mapped with one batch prefetched, or preloaded."""

    def __init__(self, records: rdata.Records, idx: np.ndarray, device, preload: bool):
        self.records, self.idx, self.device = records, idx, device
        self.x = self.y = None
        if preload and len(idx):
            x, y = records.gather(idx)
            self.x = torch.from_numpy(x).to(device)
            self.y = torch.from_numpy(y).to(device)

    def __len__(self):
        return len(self.idx)

    def iterate(self, batch: int, order: np.ndarray | None, rank: int = 0, world: int = 1):
        """Yields (x, y) tensors on the device; ``order`` permutes the rows (None: in order).
        With ``world`` > 1: this rank's rows (every ``world``-th, from ``rank``) of each global
        minibatch of ``batch`` rows."""
        for x, y, _, _ in self.iterate_global(batch, order, rank, world):
            yield x, y

    def iterate_global(self, batch: int, order: np.ndarray | None, rank: int = 0,
                       world: int = 1):
        """Like ``iterate``, yielding (x, y, global minibatch size, positions of this rank's
        rows in the global minibatch)."""
        n = len(self.idx)
        pos = np.arange(n) if order is None else order
        globs = [pos[i : i + batch] for i in range(0, n, batch)]
        chunks = [g[rank::world] for g in globs]
        where = [np.arange(len(g))[rank::world] for g in globs]
        if self.x is not None:
            for c, g, w in zip(chunks, globs, where):
                t = torch.from_numpy(c).to(self.device)
                yield self.x[t], self.y[t], len(g), w
            return

        def load(c):
            x, y = self.records.gather(self.idx[c])
            return torch.from_numpy(x), torch.from_numpy(y)

        with ThreadPoolExecutor(max_workers=1) as pool:
            fut = pool.submit(load, chunks[0]) if chunks else None
            for i in range(len(chunks)):
                x, y = fut.result()
                if i + 1 < len(chunks):
                    fut = pool.submit(load, chunks[i + 1])
                nb = self.device.type == "cuda"
                yield (x.to(self.device, non_blocking=nb), y.to(self.device, non_blocking=nb),
                       len(globs[i]), where[i])


def evaluate(model, batches: Batches, batch: int, loss_fn, dist: Dist | None = None,
             device=None) -> float | None:
    """Mean loss over ``batches``; with a process group, each rank takes its share of every
    minibatch and the sums are added up over the ranks."""
    if len(batches) == 0:
        return None
    model.eval()
    rank, world = (dist.rank, dist.world) if dist else (0, 1)
    total = 0.0
    with torch.no_grad():
        for x, y in batches.iterate(batch, None, rank, world):
            if len(y):
                total += float(loss_fn(model(x), y[:, None].expand(-1, model.outputs))) * len(y)
    if dist:
        total = dist.sum([total], device)[0]
    return total / len(batches)


def plot(log_rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    ep = [r["epoch"] for r in log_rows]
    for key, label in (("train_loss", "training"), ("val_loss", "validation"),
                       ("test_loss", "held-out clouds")):
        vals = [r[key] for r in log_rows]
        if any(v is not None and v != "" for v in vals):
            ax.plot(ep, [float(v) if v not in (None, "") else np.nan for v in vals], label=label)
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    # Whole or absent, and never written through a pipe or link left at the path.
    rexport.replace_atomically(path, lambda t: fig.savefig(t, format="png"))
    plt.close(fig)


def ema_update(ema: torch.nn.Module, model: torch.nn.Module, decay: float, step: int) -> None:
    """One step of the weights' moving average: ema <- d ema + (1 - d) model with
    d = min(decay, (1 + step) / (10 + step)), so the first steps (step counted from 0 in this
    stage) do not keep the starting weights for ~1 / (1 - decay) steps."""
    d = min(decay, (1.0 + step) / (10.0 + step))
    with torch.no_grad():
        for pe, pm in zip(ema.parameters(), model.parameters()):
            pe.lerp_(pm, 1.0 - d)
        for be, bm in zip(ema.buffers(), model.buffers()):
            be.copy_(bm)


def merged_manifest(roots: list[Path]) -> dict:
    """The manifest of one set, or of several read as one: the first one's settings (the
    others must agree on phase function, albedo and light sampling), every set's clouds."""
    ms = [rdata.read_manifest(r) for r in roots]
    if len(ms) == 1:
        return ms[0]
    first = ms[0].get("settings", {})
    for r, m in zip(roots[1:], ms[1:]):
        for key in ("phase", "albedo", "light"):
            if m.get("settings", {}).get(key) != first.get(key):
                raise SystemExit(f"--data {r}: its {key} is {m.get('settings', {}).get(key)}, "
                                 f"{roots[0]}'s {first.get(key)}")
    return {**ms[0], "clouds": [c for m in ms for c in m.get("clouds", [])],
            "convergence_rate": None}


def check_test_set(manifest: dict, test_manifest: dict, root: Path,
                   option: str = "--test-data") -> None:
    """Refuses a separate test set that does not measure the same thing (another phase
    function or albedo) or that shares a cloud with the training set (same generator, kind,
    seed and size)."""
    a, b = manifest.get("settings", {}), test_manifest.get("settings", {})
    for key in ("phase", "albedo"):
        if a.get(key) != b.get(key):
            raise SystemExit(f"{option} {root}: its {key} is {b.get(key)}, the training "
                             f"set's {a.get(key)}")

    def key(c):
        # The cloud's shape: its density scale may differ and it is still the same cloud.
        return json.dumps({k: v for k, v in c.items()
                           if k not in ("split", "name", "density_scale")}, sort_keys=True)

    train = {key(c) for c in manifest.get("clouds", []) if c.get("split") == "train"}
    shared = [c.get("name") for c in test_manifest.get("clouds", [])
              if c.get("split") == "test" and key(c) in train]
    if shared:
        raise SystemExit(f"{option} {root}: test clouds {shared} are training clouds of "
                         f"the training set")


def build_model(args) -> RPNN:
    torch.manual_seed(args.seed)
    return RPNN(levels=args.levels, width=args.width, head_layers=args.head_layers,
                outputs=args.outputs)


def load_init(model: RPNN, path: Path) -> dict:
    """Loads the starting weights of a fine-tuning stage; returns what the card records."""
    data = safe_io.read_bytes(path, what="a model (.pt checkpoint or .onnx file)")
    if path.suffix == ".onnx":
        rexport.import_onnx(model, path, data=data)
    else:
        ck = safe_io.torch_load(path, data=data)
        if not isinstance(ck, dict) or "model" not in ck:
            raise ValueError("not a checkpoint of this script (no `model` entry)")
        if ck.get("config") != model.config():
            raise SystemExit(f"{path}: checkpoint architecture {ck.get('config')} differs from "
                             f"the requested {model.config()}")
        model.load_state_dict(ck["model"])
        st = ck.get("state") or {}
    info = {"path": str(path), "sha256": hashlib.sha256(data).hexdigest()}
    card = None
    if path.suffix == ".onnx":
        try:
            card = safe_io.load_json(path.with_suffix(".json"), what="a model card (JSON)")
        except safe_io.InputError as e:
            if not e.missing:
                raise
    if isinstance(card, dict):
        # The stage before this one, as its own card describes it.
        t = card.get("training", {})
        t = t if isinstance(t, dict) else {}
        info["before"] = {k: t.get(k) for k in ("loss", "rel_eps", "epochs", "steps", "seconds",
                                                "lr", "schedule", "init")}
    elif path.suffix != ".onnx" and st.get("epoch"):
        # A checkpoint of an earlier stage: what its run state says of it (and of its own start).
        init = st.get("init") or {}
        info["before"] = {"epochs": st["epoch"], "seconds": st.get("seconds"),
                          "loss": st.get("loss"), "rel_eps": st.get("rel_eps"),
                          "init": {"path": init["path"]} if init.get("path") else None}
    return info


def train(args) -> dict:
    dist = Dist()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = pick_device(args.device, dist.local_rank)
    dist.start(device)
    try:
        result = _train(args, dist, device)
        # The DistributedDataParallel wrapper (and its reducer, which holds the process group)
        # is freed here, not at interpreter exit after the group was destroyed: gloo's threads
        # must not outlive the group ("terminate called without an active exception", twice
        # in CI at the end of a run).
        gc.collect()
        # Every rank leaves the group together: a rank that tore gloo down while rank 0 was
        # still writing its checkpoint, log and ONNX file could abort the same way.
        dist.barrier()
        return result
    finally:
        dist.stop()


def _train(args, dist: Dist, device) -> dict:
    lead = dist.rank == 0
    say = (lambda *a: None) if args.quiet or not lead else (lambda *a: print(*a, flush=True))
    manifest = merged_manifest(args.data)
    train_shards = [sh for d in args.data for sh in rdata.load_shards(d, "train",
                                                                      check=args.check)]
    val_shards = [sh for d in args.data for sh in rdata.load_shards(d, "val")]
    test_root = args.test_data or args.data[0]
    test_shards = rdata.load_shards(test_root, "test")
    if args.test_data is not None:
        check_test_set(manifest, rdata.read_manifest(args.test_data), args.test_data)
    train_recs = rdata.Records(train_shards)
    val_recs = rdata.Records(val_shards)
    test_recs = rdata.Records(test_shards)
    if len(train_recs) < 2:
        raise SystemExit(f"{', '.join(map(str, args.data))}: {len(train_recs)} training records; "
                         f"at least 2 are needed")
    if args.test_data is not None and not len(test_recs):
        raise rdata.DataError(f"--test-data {args.test_data}: no test records (its test split "
                              f"is empty)")
    if all(float(np.max(sh.y)) == 0.0 for sh in train_shards if len(sh.y)):
        raise rdata.DataError(f"{', '.join(map(str, args.data))}: every training target is 0; "
                              f"a network fitted to them predicts 0 everywhere")
    if len(val_recs):
        # Held-out validation clouds with precise labels.
        fit_idx, val_idx = np.arange(len(train_recs)), np.arange(len(val_recs))
        val_source = val_recs
    else:
        fit_idx, val_idx = rdata.split_indices(len(train_recs), args.val_fraction, args.seed)
        val_source = train_recs
    total_bytes = (len(train_recs) + len(val_recs) + len(test_recs)) * rdata.DESCRIPTOR_LEN * 4
    # Every rank on one machine would hold its own copy: the 4 GiB (and the memory budget) are
    # shared among them.
    budget = safe_io.budget()
    if args.preload == "yes" and total_bytes * dist.world > budget:
        raise SystemExit(f"error: --preload yes: the records take "
                         f"{safe_io.human(total_bytes * dist.world)}, more than the memory budget "
                         f"of {safe_io.human(budget)} (--max-memory or {safe_io.ENV}); use "
                         f"--preload auto or no")
    preload = args.preload == "yes" or (args.preload == "auto"
                                        and total_bytes * dist.world < min(4 << 30, budget))
    fit = Batches(train_recs, fit_idx, device, preload)
    val = Batches(val_source, val_idx, device, preload)
    test = Batches(test_recs, np.arange(len(test_recs)), device, preload)
    loss_fn = LOSSES[args.loss]
    if args.loss == "rel-l2":
        loss_fn = functools.partial(loss_fn, eps=args.rel_eps)
    mirror = mirror_columns(args.levels).to(device) if args.mirror else None
    if not 0.0 <= args.axis_turns <= 90.0:
        raise SystemExit(f"--axis-turns must lie in [0, 90] degrees, got {args.axis_turns}")
    turn = quarter_turn_columns(args.levels).to(device) if args.axis_turns > 0 else None

    model = build_model(args)
    model.init_output_bias(float(np.mean(train_recs.gather(fit_idx[:200_000])[1])))
    init = None
    if args.init is not None and not (args.resume and (args.run / "last.pt").exists()):
        try:
            init = load_init(model, args.init)
        except (SystemExit, safe_io.InputError):
            raise
        except Exception as e:  # a file that is not a model of this architecture
            raise SystemExit(f"error: --init {args.init}: cannot start from it "
                             f"({type(e).__name__}: {e})") from None
        say(f"initialised from {args.init}")
    model = model.to(device)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    if lead:
        args.run.mkdir(parents=True, exist_ok=True)
    last, best = args.run / "last.pt", args.run / "best.pt"
    # The weights' moving average (--ema): a copy that follows the trained weights.
    ema = None
    if args.ema > 0:
        import copy

        ema = copy.deepcopy(model)
    # What a resumed run must share with the run it continues. The sets by what made them (the
    # datagen settings but the record counts, and the clouds), not by their manifests or
    # folders: a set may grow between stages (training/reproduce.sh extends it, a run's records
    # being a prefix of any longer run's), and a run may move to another machine or checkout.
    run_settings = {"data": [rdata.set_identity(d) for d in args.data],
                    "test_data": rdata.set_identity(args.test_data) if args.test_data else None,
                    "lr": args.lr, "schedule": args.schedule, "batch": args.batch,
                    "seed": args.seed, "mirror": args.mirror, "axis_turns": args.axis_turns,
                    "epochs": args.epochs}
    state = {"epoch": 0, "best_val": float("inf"), "best_epoch": 0, "log": [], "seconds": 0.0,
             "init": init, "loss": args.loss, "rel_eps": args.rel_eps, "ema": args.ema,
             "ema_steps": 0, "run_settings": run_settings}
    if args.resume and last.exists():
        try:
            ck = safe_io.torch_load(last, map_location=device)
            if not (isinstance(ck, dict) and {"config", "state", "model", "optimizer"} <= set(ck)):
                raise ValueError("not a checkpoint of this script")
        except safe_io.InputError:
            raise  # a pipe, a device, a link to nothing, a file over the budget: said as such
        except Exception as e:  # torch raises many kinds on a damaged file
            raise SystemExit(f"error: {last}: cannot resume from it ({type(e).__name__}: {e}); "
                             f"remove it to start over, or use a new --run") from None
        had = ck["state"].get("run_settings") or {}
        # --epochs may grow (a longer run); everything else must match.
        differs = [k for k in run_settings if k in had and k != "epochs"
                   and had[k] != run_settings[k]]
        if differs:
            raise SystemExit(f"error: {last}: trained with other settings ("
                             + ", ".join(f"{k}: was {had[k]}, now {run_settings[k]}"
                                         for k in differs)
                             + "); resuming would mix two runs: use a new --run")
        if ck["config"] != model.config():
            raise SystemExit(f"{last}: checkpoint architecture {ck['config']} differs from "
                             f"the requested {model.config()}")
        saved = ck["state"]
        if (saved.get("loss", args.loss), saved.get("rel_eps", args.rel_eps)) != (args.loss,
                                                                               args.rel_eps):
            raise SystemExit(f"{last}: trained with --loss {saved.get('loss')} --rel-eps "
                             f"{saved.get('rel_eps')}; resuming with --loss {args.loss} "
                             f"--rel-eps {args.rel_eps} would mix two losses")
        if saved.get("ema", 0.0) != args.ema:
            raise SystemExit(f"{last}: trained with --ema {saved.get('ema', 0.0)}; resuming "
                             f"with --ema {args.ema} would mix two averages")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        if ema is not None:
            ema.load_state_dict(ck["ema"])
        state = saved
        state["run_settings"] = run_settings
        say(f"resumed from {last} after epoch {state['epoch']}")
    # DDP after loading: it broadcasts rank 0's parameters to the others.
    net = torch.nn.parallel.DistributedDataParallel(model) if dist.on else model
    ranks = f"; {dist.world} ranks ({'nccl' if device.type == 'cuda' else 'gloo'})" if dist.on else ""
    say(f"RPNN {model.config()}: {parameter_count(model):,} parameters; device {device}{ranks}; "
        f"{len(fit)} fitting / {len(val)} validation / {len(test)} test records; "
        f"{'preloaded' if preload else 'memory-mapped'}; loss {args.loss}"
        f"{', mirrored' if mirror is not None else ''}")

    # What is validated, kept as best.pt and exported: the average when there is one.
    scored = ema if ema is not None else model
    if not state["log"]:
        # Epoch 0: the untrained network (a constant near the mean target), the baseline of the
        # learning curves.
        state["log"].append({"epoch": 0, "train_loss": None,
                             "val_loss": evaluate(scored, val, 4 * args.batch, loss_fn, dist,
                                                  device),
                             "test_loss": evaluate(scored, test, 4 * args.batch, loss_fn, dist,
                                                   device),
                             "seconds": 0.0})
    steps_per_epoch = -(-len(fit) // args.batch)
    for epoch in range(state["epoch"] + 1, args.epochs + 1):
        if args.max_minutes and state["seconds"] >= 60 * args.max_minutes:
            say(f"stopping: {state['seconds'] / 60:.1f} min of training (--max-minutes)")
            break
        t0 = time.time()
        net.train()
        # The same global order and mirroring on every rank (they depend on seed and epoch only).
        order = np.random.default_rng([args.seed, epoch]).permutation(len(fit))
        flip_rng = torch.Generator().manual_seed(args.seed * 1_000_003 + epoch)
        turn_rng = torch.Generator().manual_seed(args.seed * 1_000_033 + epoch)
        tl, tn = 0.0, 0
        batches = fit.iterate_global(args.batch, order, dist.rank, dist.world)
        for step, (x, y, n_global, where) in enumerate(batches):
            if args.schedule == "cosine":
                t = ((epoch - 1) * steps_per_epoch + step) / max(args.epochs * steps_per_epoch, 1)
                for gr in opt.param_groups:
                    gr["lr"] = args.lr * 0.5 * (1.0 + np.cos(np.pi * t))
            if mirror is not None:
                flip = torch.rand(n_global, generator=flip_rng) < 0.5
                flip = flip[torch.from_numpy(where)].to(x.device)
                x = torch.where(flip[:, None], x[:, mirror], x)
            if turn is not None:
                q = torch.randint(0, 4, (n_global,), generator=turn_rng)
                x = axis_turns(x, np.radians(args.axis_turns), turn, q[torch.from_numpy(where)])
            # This rank's share of the global mean: DDP averages the gradients over the ranks.
            share = len(y) * dist.world / n_global
            if len(y) == 0:
                # A last minibatch smaller than the world: take part in the gradient exchange
                # with a zero-weight row.
                x, y, share = torch.zeros((1, x.shape[1]), device=device), torch.ones(
                    1, device=device), 0.0
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net(x), y[:, None].expand(-1, model.outputs))
            (loss * share).backward()
            opt.step()
            if ema is not None:
                ema_update(ema, model, args.ema, state["ema_steps"])
                state["ema_steps"] += 1
            tl += float(loss.detach()) * len(y) * (share > 0)
            tn += len(y) * (share > 0)
        if dist.on:
            tl, tn = dist.sum([tl, tn], device)
        vl = evaluate(scored, val, 4 * args.batch, loss_fn, dist, device)
        te = evaluate(scored, test, 4 * args.batch, loss_fn, dist, device)
        # Every rank keeps the same clock (--max-minutes must stop them together).
        dt = dist.max(time.time() - t0, device)
        state["seconds"] += dt
        state["epoch"] = epoch
        row = {"epoch": epoch, "train_loss": tl / max(tn, 1), "val_loss": vl,
               "test_loss": te, "seconds": state["seconds"]}
        state["log"].append(row)
        if not (np.isfinite(row["train_loss"]) and np.isfinite(vl)):
            raise SystemExit(f"error: training diverged at epoch {epoch} (training loss "
                             f"{row['train_loss']}, validation loss {vl}): lower --lr (now "
                             f"{args.lr}) or check the data; {args.run} keeps the last finite "
                             f"epoch's checkpoints")
        improved = vl < state["best_val"] or args.select == "last"
        if improved:
            state["best_val"], state["best_epoch"] = vl, epoch
        if lead:
            # Whole or absent: a run killed while saving keeps the previous checkpoint.
            if improved:
                rexport.replace_atomically(best, lambda t: torch.save(
                    {"model": scored.state_dict(), "config": model.config(), "epoch": epoch}, t))
            rexport.replace_atomically(last, lambda t: torch.save(
                {"model": model.state_dict(), "optimizer": opt.state_dict(),
                 "config": model.config(), "state": state,
                 **({"ema": ema.state_dict()} if ema is not None else {})}, t))
            def write_log(t, log=state["log"], fields=list(row)):
                with open(t, "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=fields)
                    w.writeheader()
                    w.writerows(log)

            rexport.replace_atomically(args.run / "log.csv", write_log)
            plot(state["log"], args.run / "curves.png")
        te_s = "" if te is None else f", test {te:.5g}"
        say(f"epoch {epoch}: train {row['train_loss']:.5g}, validation {vl:.5g}{te_s} ({dt:.1f} s)")

    result = {"state": state, "manifest": manifest, "fit": len(fit), "val": len(val),
              "test": len(test), "device": str(device), "val_from_clouds": bool(len(val_recs)),
              "ranks": dist.world}
    if args.export and lead:
        result["card"] = export(args, result, val_source, val_idx, test_recs, device)
        say(f"wrote {args.export} (export check: max relative difference "
            f"{result['card']['export_check']['max_relative_difference']:.2e})")
    return result


def blend_with_init(model: RPNN, state: dict, w: float) -> dict:
    """(1 - w) x the run's starting weights + w x ``model``'s (``--blend-init``)."""
    init = (state.get("init") or {}).get("path")
    if not init:
        raise SystemExit("--blend-init needs a run that started from --init weights")
    start = RPNN(**model.config())
    info = load_init(start, Path(init))
    if info["sha256"] != state["init"].get("sha256"):
        # e.g. the export replaced the model the run started from: blending with the new file
        # would silently blend the wrong weights.
        was = state["init"].get("sha256") or "?"
        raise SystemExit(f"--blend-init: {init} is no longer the file this run started from "
                         f"(sha256 {info['sha256'][:16]}…, the run's {was[:16]}…)")
    a, b = start.state_dict(), model.state_dict()
    return {k: (1.0 - w) * a[k] + w * b[k] if b[k].is_floating_point() else b[k] for k in b}


def export(args, result, val_source, val_idx, test_recs, device) -> dict:
    best = args.run / "best.pt"
    if not best.exists():
        raise SystemExit(f"{best}: no checkpoint to export (train at least one epoch)")
    ck = safe_io.torch_load(best)
    model = RPNN(**ck["config"])
    model.load_state_dict(ck["model"])
    if args.blend_init < 1.0:
        ck["model"] = blend_with_init(model, result["state"], args.blend_init)
        model.load_state_dict(ck["model"])
    m = result["manifest"]
    rexport.export_onnx(model, args.export, {
        "nimbus.rpnn.phase": m.get("settings", {}).get("phase", "unknown"),
        "nimbus.rpnn.albedo": str(m.get("settings", {}).get("albedo", "unknown")),
        "nimbus.rpnn.data_manifest_sha256": ",".join(rdata.manifest_hash(d) for d in args.data),
    })
    # Per-record errors of the best model on the precise splits.
    dev_model = RPNN(**ck["config"])
    dev_model.load_state_dict(ck["model"])
    dev_model = dev_model.to(device)
    test_root = args.test_data or args.data[0]
    errors = {
        "validation": record_errors(dev_model, Batches(val_source, val_idx, device, False),
                                    4 * args.batch),
        "test": with_label_noise(record_errors(
            dev_model, Batches(test_recs, np.arange(len(test_recs)), device, False),
            4 * args.batch, rdata.cloud_kinds(test_root, "test")), test_root, "test"),
    }
    if result["val_from_clouds"]:
        errors["validation"] = with_label_noise(errors["validation"], args.data, "val")
    # Check on real records: validation rows, then held-out ones (up to 2000 in all).
    xv, _ = val_source.gather(val_idx[:1000])
    rows = [xv]
    if len(test_recs):
        rows.append(test_recs.gather(np.arange(min(1000, len(test_recs))))[0])
    check = rexport.verify(model, args.export, np.concatenate(rows))
    s = result["state"]
    cfg = model.config()
    settings = m.get("settings", {})
    splits = [c.get("split") for c in m.get("clouds", [])]
    test_set = None
    if args.test_data is not None:
        tm = rdata.read_manifest(args.test_data)
        ts = tm.get("settings", {})
        test_set = {"root": str(args.test_data), "manifest_sha256":
                    rdata.manifest_hash(args.test_data), "seed": ts.get("seed"),
                    "eval_samples": ts.get("eval_samples"), "eval_noise": ts.get("eval_noise"),
                    "test_clouds": [c.get("split") for c in tm.get("clouds", [])].count("test")}
    samples = [rdata.read_manifest(d).get("settings", {}).get("samples") for d in args.data]
    card = {
        "model": Path(args.export).name,
        "architecture": {**cfg, "input_len": model.input_len,
                         "layers": 2 * cfg["levels"] + cfg["head_layers"],
                         "parameters": parameter_count(model),
                         "input": rexport.INPUT_NAME, "output": rexport.OUTPUT_NAME,
                         "opset": rexport.OPSET},
        "data": {"root": ", ".join(map(str, args.data)),
                 "manifest_sha256": ", ".join(rdata.manifest_hash(d) for d in args.data),
                 "phase": settings.get("phase"), "albedo": settings.get("albedo"),
                 "seed": settings.get("seed"), "max_samples": settings.get("max_samples"),
                 "samples": samples[0] if len(set(samples)) == 1 else samples,
                 "eval_samples": settings.get("eval_samples"),
                 "light": settings.get("light"),
                 "train_clouds": splits.count("train"), "val_clouds": splits.count("val"),
                 "test_clouds": (test_set["test_clouds"] if test_set
                                 else splits.count("test")),
                 "test_set": test_set,
                 "clouds": m.get("clouds", []),
                 "train_records": result["fit"] + (0 if result["val_from_clouds"]
                                                   else result["val"]),
                 "val_records": result["val"] if result["val_from_clouds"] else 0,
                 "test_records": result["test"],
                 "convergence_rate": m.get("convergence_rate")},
        "training": {"loss": args.loss,
                     "rel_eps": args.rel_eps if args.loss == "rel-l2" else None,
                     "init": s.get("init"), "blend_init": args.blend_init,
                     "mirror": args.mirror, "ema": args.ema,
                     "axis_turns_deg": args.axis_turns, "schedule": args.schedule,
                     "steps": s["epoch"] * -(-result["fit"] // args.batch),
                     "epochs": s["epoch"], "best_epoch": s["best_epoch"],
                     "select": args.select,
                     "best_val_loss": s["best_val"],
                     "test_loss": next((r["test_loss"] for r in s["log"]
                                        if r["epoch"] == s["best_epoch"]), None),
                     "train_rows": result["fit"], "val_rows": result["val"],
                     "batch": args.batch, "lr": args.lr, "seed": args.seed,
                     "device": result["device"], "ranks": result.get("ranks", 1),
                     "seconds": s["seconds"],
                     "torch": torch.__version__},
        "record_errors": errors,
        "export_check": check,
        # The file this card describes (evaluate.py --card refuses a card whose file changed).
        "model_sha256": safe_io.sha256_file(args.export),
        "reproduce": args.reproduce or " ".join(["python"] + sys.argv),
    }
    rexport.write_card(args.export, card)
    if not check["passed"]:
        raise SystemExit(f"{args.export}: onnxruntime and torch differ by "
                         f"{check['max_relative_difference']:.2e} (> 1e-5)")
    return card


def check_writable(path: Path, flag: str, folder: bool) -> None:
    """Before training: the run folder (or the export's folder) can be made and written, so
    that a bad path fails now and not after the last epoch."""
    d = path if folder else path.parent
    if path.exists() and path.is_dir() != folder:
        raise SystemExit(f"error: {flag} {path}: {'not a folder' if folder else 'a folder'}")
    try:
        d.mkdir(parents=True, exist_ok=True)
        probe = d / f".write-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise SystemExit(f"error: {flag} {path}: cannot be written ({e.strerror or e})") from None


def main(argv=None):
    # A set or file that cannot be used (the message names it): one line, exit status 2.
    with safe_io.reporting_input_errors():
        args = parse_args(argv)
        if Dist().rank == 0:
            check_writable(args.run, "--run", True)
            if args.export:
                check_writable(args.export, "--export", False)
        try:
            train(args)
        except (OSError, EOFError) as e:
            # A folder that cannot be written (the messages name it).
            raise SystemExit(f"error: {e}") from None
    if Dist().on:
        # A rank of a torchrun launch leaves without the interpreter's teardown: every file is
        # written and closed and the process group left, and the C++ destructors that would run
        # next (gloo's and the store's threads) have aborted a finished run ("terminate called
        # without an active exception", CI).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


if __name__ == "__main__":
    main()
