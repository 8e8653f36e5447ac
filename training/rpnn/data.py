"""Reading ``nimbus datagen`` record sets (layout: crates/rpnn/src/data/dataset.rs).

Shards are memory-mapped (``np.load(mmap_mode="r")``) so a set larger than memory trains without
being read in full; minibatches gather their rows shard by shard in sorted order. With
``preload=True`` the rows are copied into one array (or onto the GPU by the trainer) once, which is
what keeps a GPU fed when the set fits in memory.
"""

from __future__ import annotations

import hashlib
import json
import mmap
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import safe_io
from .model import DESCRIPTOR_LEN
from .safe_io import InputError

FORMAT = "nimbus-rpnn-records/2"
# Version 1 (13 meta columns, no validation split) reads the same way.
FORMATS = ("nimbus-rpnn-records/1", FORMAT)


# The largest target accepted: indirect radiance per unit sun irradiance is O(1) (the sets'
# largest are ~ 1.2); a label a million times that is a corrupt file, and would make the
# network fit it alone.
MAX_TARGET = 1e6


class DataError(InputError):
    """A record set that cannot be used; the message names the file and the field."""


@dataclass
class Shard:
    x: np.ndarray  # [n, 2251] float32 or float16 (memory-mapped)
    y: np.ndarray  # [n] float32
    path: Path
    # float16 descriptors: gamma in float32, recomputed from the meta's directions (the network
    # is sensitive to gamma's rounding: 2.6e-3 relative with a float16 gamma, 7e-4 without).
    gamma: np.ndarray | None = None


def gamma_of(meta: np.ndarray) -> np.ndarray:
    """gamma = angle(view, light) from meta columns 4..6 and 7..9, as the descriptor computes it
    (atan2(|v x l|, v . l))."""
    v = meta[:, 4:7].astype(np.float64)
    l = meta[:, 7:10].astype(np.float64)
    return np.arctan2(np.linalg.norm(np.cross(v, l), axis=1), (v * l).sum(axis=1)).astype(
        np.float32)


def manifest_hash(root: Path) -> str:
    return hashlib.sha256(safe_io.read_bytes(Path(root) / "manifest.json")).hexdigest()


def set_identity(root: Path) -> str:
    """What made a set, as a hash: its datagen settings but the record counts (a set may grow,
    its records being a prefix of any longer run's) and its clouds. Equal for the same set in
    another folder or on another machine."""
    m = read_manifest(root)
    grows = ("records", "val_records", "test_records", "progress", "gpu", "part")
    what = {"settings": {k: v for k, v in m.get("settings", {}).items() if k not in grows},
            "clouds": m.get("clouds", [])}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()


def read_manifest(root: Path) -> dict:
    path = Path(root) / "manifest.json"
    try:
        os.stat(root)
    except OSError as e:
        err = safe_io.os_error(root, e)
        if not err.missing:  # a link loop or a link to nothing, said as such
            raise DataError(str(err)) from None
    if Path(root).exists() and not Path(root).is_dir():
        raise DataError(f"{root}: not a folder (a `nimbus datagen --out` folder is expected)")
    try:
        m = safe_io.load_json(path, what="the set's manifest (a JSON file)")
    except InputError as e:
        if e.missing:
            raise DataError(f"{path}: not found (run `nimbus datagen --out {root}` first)") \
                from None
        raise DataError(str(e)) from None
    if not isinstance(m, dict):
        raise DataError(f"{path}: expected a JSON object, got {type(m).__name__}")
    if m.get("format") not in FORMATS:
        raise DataError(f"{path}: field 'format' is {m.get('format')!r}, expected one of {FORMATS}")
    if m.get("descriptor_len") != DESCRIPTOR_LEN:
        raise DataError(
            f"{path}: field 'descriptor_len' is {m.get('descriptor_len')}, expected {DESCRIPTOR_LEN}"
        )
    if not isinstance(m.get("shards"), list):
        raise DataError(f"{path}: field 'shards' is missing or not a list")
    if not isinstance(m.get("settings", {}), dict):
        raise DataError(f"{path}: field 'settings' is not an object")
    for i, sh in enumerate(m["shards"]):
        if not isinstance(sh, dict):
            raise DataError(f"{path}: shards[{i}] is not an object")
        for key in ("x", "y", "meta"):
            f = sh.get(key)
            if key in sh and not (isinstance(f, str) and f and Path(f).name == f):
                # A shard is a file name inside the set's folder: not a path that leaves it.
                raise DataError(f"{path}: shards[{i}].{key} is {f!r}, expected a file name in "
                                f"the set's folder")
        sums = sh.get("sha256")
        if "sha256" in sh and not (isinstance(sums, list) and len(sums) == 3 and all(
                isinstance(h, str) and len(h) == 64 and all(c in "0123456789abcdef" for c in h)
                for h in sums)):
            raise DataError(f"{path}: shards[{i}].sha256 is {sums!r:.120}, expected the hex "
                            f"SHA-256 of the x, y and meta files (3 strings of 64 digits)")
        if "records" in sh and not (isinstance(sh["records"], int)
                                    and not isinstance(sh["records"], bool)
                                    and sh["records"] >= 0):
            raise DataError(f"{path}: shards[{i}].records is {sh['records']!r}, expected a "
                            f"whole number >= 0")
    return m


class _Sums:
    """The manifest's SHA-256 of one shard's files (none for sets written before there were
    any): each file is hashed from the bytes it is read from and compared."""

    def __init__(self, manifest: Path, i: int, entry: dict, check: bool):
        self.manifest, self.i = manifest, i
        self.want = entry.get("sha256") if check else None

    def verify(self, path: Path, which: int, have: str | None) -> None:
        if self.want is None or have is None:
            return
        want = self.want[which]
        if have != want:
            raise DataError(f"{path}: SHA-256 {have[:16]}… differs from the manifest's "
                            f"shards[{self.i}].sha256[{which}] ({want[:16]}…) in "
                            f"{self.manifest}: the file is damaged or was changed after datagen "
                            f"wrote it (rerunning the `nimbus datagen` command that wrote the set "
                            f"recomputes it)")


def _read_npy(path: Path, sums: _Sums | None = None, which: int = 0) -> np.ndarray:
    """A memory-mapped .npy array (DataError naming the file when unreadable or when its
    SHA-256 is not the manifest's)."""
    digest = sums is not None and sums.want is not None
    try:
        got = safe_io.load_npy(path, mmap=True, digest=digest)
    except InputError as e:
        if e.missing:
            raise DataError(f"{path}: not found (the manifest lists it)") from None
        raise DataError(str(e)) from None
    if digest:
        got, have = got
        sums.verify(path, which, have)
    return got


def _load(path: Path, shape_tail: tuple, dtypes=(np.float32,), sums: _Sums | None = None,
          which: int = 0) -> np.ndarray:
    a = _read_npy(path, sums, which)
    if not isinstance(a, np.ndarray) or a.ndim == 0:
        raise DataError(f"{path}: not an array")
    if a.dtype not in dtypes or a.shape[1:] != shape_tail:
        names = " or ".join(np.dtype(d).name for d in dtypes)
        raise DataError(f"{path}: expected {names} [n{''.join(f', {d}' for d in shape_tail)}], "
                        f"got {a.dtype} {list(a.shape)}")
    return a


def _load_any(path: Path, sums: _Sums | None = None, which: int = 2) -> np.ndarray:
    """A memory-mapped .npy array of any shape (DataError naming the file when unreadable)."""
    return _read_npy(path, sums, which)


def advise_random(a: np.ndarray) -> None:
    """Tells the kernel that a memory-mapped array is read at random rows: no readahead. A
    shuffled epoch over a set larger than the page cache otherwise reads ~30x the rows it uses
    (each miss pulls in a readahead window that evicts rows still needed; measured on a 26 GB
    set with 22 GB of cache: 0.7 GB/s of disk reads and the trainer at half a core)."""
    m = getattr(a, "_mmap", None)
    if m is not None and hasattr(m, "madvise") and hasattr(mmap, "MADV_RANDOM"):
        m.madvise(mmap.MADV_RANDOM)


def load_shards(root: Path, split: str, check: bool = True) -> list[Shard]:
    """The shards of ``split`` ("train", "val" or "test"), checked for shape and finite values
    and, where the manifest lists them (field ``shards[i].sha256``), against the SHA-256 of
    their x, y and meta files. ``check=False`` (``train.py --no-check``) trusts the set: neither
    the values nor the sums are checked, so a set larger than the page cache is not read in
    full at the start."""
    root = Path(root)
    m = read_manifest(root)
    shards = []
    for i, s in enumerate(m["shards"]):
        if s.get("split") != split:
            continue
        for key in ("x", "y", "records"):
            if key not in s:
                raise DataError(f"{root / 'manifest.json'}: shards[{i}] has no field '{key}'")
        sums = _Sums(root / "manifest.json", i, s, check)
        if sums.want is not None and "meta" not in s:
            raise DataError(f"{root / 'manifest.json'}: shards[{i}] has field 'sha256' but no "
                            f"field 'meta'")
        x = _load(root / s["x"], (DESCRIPTOR_LEN,), (np.float32, np.float16), sums, 0)
        y = _load(root / s["y"], (), sums=sums, which=1)
        meta = _load_any(root / s["meta"], sums, 2) if sums.want is not None else None
        gamma = None
        if x.dtype == np.float16:
            if "meta" not in s:
                raise DataError(f"{root / 'manifest.json'}: shards[{i}] has float16 descriptors "
                                f"but no field 'meta' (gamma is taken from it)")
            if meta is None:
                meta = _load_any(root / s["meta"])
            if meta.ndim != 2 or meta.shape[0] != len(x) or meta.shape[1] < 10:
                raise DataError(f"{root / s['meta']}: expected [n >= {len(x)}, >= 10] meta, "
                                f"got {list(meta.shape)}")
            gamma = gamma_of(np.asarray(meta))
            bad = np.flatnonzero(~np.isfinite(gamma))
            if bad.size:
                raise DataError(f"{root / s['meta']}: row {bad[0]}'s view or light direction "
                                f"(columns 4..9) is not finite; gamma is taken from them")
        if len(x) != s["records"] or len(y) != s["records"]:
            raise DataError(f"{root / s['x']}: {len(x)} rows of x and {len(y)} of y, "
                            f"manifest field shards[{i}].records says {s['records']}")
        if check:
            bad = np.flatnonzero(~np.isfinite(y) | (y < 0) | (y > MAX_TARGET))
            if bad.size:
                raise DataError(f"{root / s['y']}: row {bad[0]} is {y[bad[0]]}; targets must be "
                                f"finite and in [0, {MAX_TARGET:g}] (radiance per unit "
                                f"irradiance)")
            rows = np.flatnonzero(~np.isfinite(x).all(axis=1))
            if rows.size:
                raise DataError(f"{root / s['x']}: row {rows[0]} has a non-finite descriptor value")
        advise_random(x)  # after the sequential check above, which readahead helps
        shards.append(Shard(x=x, y=y, path=root / s["x"], gamma=gamma))
    return shards


class Records:
    """Rows of several shards addressed by one global index."""

    def __init__(self, shards: list[Shard]):
        self.shards = shards
        sizes = np.array([len(s.y) for s in shards], dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(sizes)])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def gather(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x [len(idx), 2251], y [len(idx)]) for global row indices ``idx``, in that order."""
        idx = np.asarray(idx, dtype=np.int64)
        x = np.empty((len(idx), DESCRIPTOR_LEN), dtype=np.float32)
        y = np.empty(len(idx), dtype=np.float32)
        shard_of = np.searchsorted(self.offsets, idx, side="right") - 1
        for s in np.unique(shard_of):
            sel = np.flatnonzero(shard_of == s)
            local = idx[sel] - self.offsets[s]
            order = np.argsort(local)  # sorted reads are sequential on a memory map
            sh = self.shards[s]
            x[sel[order]] = sh.x[local[order]]
            if sh.gamma is not None:
                x[sel[order], -1] = sh.gamma[local[order]]
            y[sel[order]] = sh.y[local[order]]
        return x, y


def _split_meta(root: Path, split: str):
    """(shard entry, its meta array memory-mapped or None) for each shard of `split`."""
    for s in read_manifest(root).get("shards", []):
        if s.get("split") == split:
            yield s, (_load_any(root / s["meta"]) if s.get("meta") else None)


def label_noise(root: Path, split: str) -> np.ndarray:
    """Relative standard deviation of every label of `split` (NaN where unknown)."""
    out = []
    for s, meta in _split_meta(root, split):
        y = _load_any(root / s["y"]).astype(np.float64)
        if meta is None or meta.ndim != 2 or meta.shape[1] <= 13:  # no label variance
            out.append(np.full(len(y), np.nan))
            continue
        var = meta[:, 13].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            out.append(np.where(y > 0, np.sqrt(np.maximum(var, 0)) / y, np.nan))
    return np.concatenate(out) if out else np.zeros(0)


def cloud_kinds(root: Path, split: str) -> np.ndarray:
    """The cloud kind (the manifest's `clouds[i].kind`: cumulus, stratus, cirrus, ...; a cloud
    read from a file: its name) of every record of `split`, in row order; "unknown" where the
    meta or the manifest does not say."""
    root = Path(root)
    m = read_manifest(root)
    names = []
    for c in m.get("clouds", []):
        c = c if isinstance(c, dict) else {}
        names.append(str(c.get("kind") or c.get("name") or "unknown"))
    out = []
    for s, meta in _split_meta(root, split):
        n = int(s.get("records", 0))
        if meta is None or meta.ndim != 2 or meta.shape[0] != n or meta.shape[1] < 1:
            out.append(np.full(n, "unknown", dtype=object))
            continue
        col = np.asarray(meta[:, 0], dtype=np.float64)
        ok = np.isfinite(col) & (col >= 0) & (col < len(names)) & (col == np.round(col))
        k = np.full(n, "unknown", dtype=object)
        k[ok] = [names[int(i)] for i in col[ok]]
        out.append(k)
    return np.concatenate(out) if out else np.zeros(0, dtype=object)


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A fixed random split of n rows: (train, validation)."""
    if not 0.0 < val_fraction < 1.0:
        raise DataError(f"validation fraction must lie in (0, 1), got {val_fraction}")
    perm = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(n * val_fraction)))
    if n - n_val < 1:
        raise DataError(f"{n} records are too few to split into training and validation")
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])
