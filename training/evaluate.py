#!/usr/bin/env python3
"""Per-record error of a shipped ONNX model on a record set's precise splits (validation and
test clouds), as the model card reports it, plus the part of it that is label noise.

    python training/evaluate.py --data out/rpnn-hg-data --model models/rpnn-hg.onnx

The labels of the precise splits are Monte Carlo estimates themselves (e.g. 16 384 samples):
their own relative standard deviation sqrt(target_variance) / y (meta column
``target_variance``: the sample variance over the sample count) is printed as the median label noise, and the "noise
floor" is the median relative error a perfect model would show against such labels (simulated:
|N(0, s_i)| per record). The errors themselves are never corrected for it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from rpnn import data as rdata  # noqa: E402
from rpnn import export as rexport  # noqa: E402
from rpnn import safe_io  # noqa: E402
from rpnn.model import RPNN  # noqa: E402

import train  # noqa: E402


def main(argv=None) -> dict:
    # A set or file that cannot be used (the message names it): one line, exit status 2.
    with safe_io.reporting_input_errors():
        return _main(argv)


def _main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, type=Path)
    p.add_argument("--model", required=True, type=Path, help="an ONNX file written by train.py")
    p.add_argument("--json", type=Path, help="also write the result here")
    p.add_argument("--split", action="append", choices=["val", "test", "train"],
                   help="the splits to score (repeatable; default: val and test). `train`: e.g. "
                        "the fixed-count records of one cloud read from a folder (`nimbus "
                        "datagen --clouds DIR --samples 4096 …`), whose per-gamma mean ratio "
                        "is the network's bias on that cloud")
    p.add_argument("--card", action="store_true",
                   help="add the test split's errors to the model's card (<model>.json and .md) "
                        "as a further held-out set, replacing an entry for the same set: the "
                        "card then shows held-out clouds beyond its own test set (e.g. sets no "
                        "stage selected on)")
    p.add_argument("--max-memory", metavar="SIZE",
                   help="memory budget (6G, 512M, bytes): no file larger is read (default: "
                        "NIMBUS_MAX_MEMORY, else 3/4 of the physical memory or of the cgroup's "
                        "limit)")
    args = p.parse_args(argv)
    try:
        safe_io.set_budget(None if args.max_memory is None else
                           safe_io.parse_size(args.max_memory))
    except ValueError as e:
        p.error(f"--max-memory {e}")
    if args.card:
        if args.split and args.split != ["test"]:
            p.error("--card records the test split only (drop --split or give --split test)")
        args.split = ["test"]
        card, model_sha = card_entry(args.model, args.data)
    model, meta = load_model(args.model)
    manifest = rdata.read_manifest(args.data)
    # A model scored on records of another medium measures nothing (the renderer warns too).
    st = manifest.get("settings", {})
    for key in ("phase", "albedo"):
        have, want = meta.get(f"nimbus.rpnn.{key}"), st.get(key)
        if have in (None, "unknown") or want is None:
            continue
        if key == "albedo":
            try:
                differs = abs(float(have) - float(want)) > 1e-9
            except (TypeError, ValueError):
                differs = True
        else:
            differs = str(have) != str(want)
        if differs:
            raise SystemExit(f"error: {args.model} was trained for {key} {have}, the records "
                             f"of {args.data} have {key} {want}")
    result = {"model": str(args.model), "data": str(args.data)}
    names = {"val": "validation", "test": "test", "train": "training"}
    for split in args.split or ["val", "test"]:
        name = names[split]
        recs = rdata.Records(rdata.load_shards(args.data, split))
        if not len(recs):
            if args.split:
                # Asked for by name: say so rather than print nothing.
                raise SystemExit(f"error: {args.data}: no {name} records (split `{split}`)")
            continue
        err = train.record_errors(model, train.Batches(recs, np.arange(len(recs)),
                                                       torch.device("cpu"), False), 4000,
                                  rdata.cloud_kinds(args.data, split))
        if err is None:
            raise SystemExit(f"error: {args.data}: the {name} records have no positive target; "
                             f"relative errors are undefined")
        train.with_label_noise(err, args.data, split)
        result[name] = err
        print(f"{name}: {err['records']} records, median relative error "
              f"{100 * err['median_rel_error']:.1f} %, mean ratio {err['mean_ratio']:.3f}; "
              f"label noise median {100 * (err['label_noise_median'] or 0):.1f} % "
              f"(a perfect model: {100 * (err['noise_floor_median'] or 0):.1f} %)")
        for line in rexport.record_error_lines({name: err})[1:]:
            if line.strip():
                print(line)
    if len(result) == 2:
        raise SystemExit(f"error: {args.data}: no validation or test records to score (give "
                         f"--split train for a set of training records)")
    if args.card:
        add_to_card(args.model, model_sha, card, result["test"])
    if args.json:
        try:
            rexport.replace_atomically(
                args.json, lambda t: t.write_text(json.dumps(result, indent=1)))
        except OSError as e:
            raise SystemExit(f"error: --json {args.json}: {e}") from None
    return result


def load_model(path: Path) -> tuple[RPNN, dict]:
    """The network of an ONNX file written by train.py and its metadata; errors name the file."""
    import onnx
    from google.protobuf.message import DecodeError

    try:
        data = safe_io.read_bytes(path, what="an ONNX file written by train.py (--model)")
    except safe_io.InputError as e:
        if e.missing:
            raise safe_io.InputError(f"{e} (--model names an ONNX file written by train.py)",
                                     missing=True) from None
        raise
    try:
        meta = {m.key: m.value for m in onnx.load_from_string(data).metadata_props}
        config = json.loads(meta.get("nimbus.rpnn.config", "{}")) or {}
        if not isinstance(config, dict):
            raise ValueError("metadata field `nimbus.rpnn.config` is not a JSON object")
        model = RPNN(**config)
        rexport.import_onnx(model, path, data=data)
    except safe_io.InputError:
        raise
    except (DecodeError, OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"error: {path}: not a readable RPNN model ({e})") from None
    except (ValueError, TypeError) as e:
        raise SystemExit(f"error: {path}: field `nimbus.rpnn.config` or the weights: {e}") from None
    except Exception as e:  # onnxruntime's own kinds (a graph it cannot run, say)
        raise SystemExit(f"error: {path}: not a usable RPNN model ({type(e).__name__}: {e})") \
            from None
    return model, meta


def card_entry(model: Path, root: Path) -> tuple[dict, str]:
    """Before scoring (``--card``): the model's card must exist, and ``root`` must measure the
    same thing as its training set and share no cloud with it (train.py's ``--test-data``
    check). Returns the card's entry for ``root`` without the errors, and the model file's
    sha256."""
    card_path = model.with_suffix(".json")
    try:
        card = safe_io.load_json(card_path, what="a model card (JSON)")
    except safe_io.InputError as e:
        if e.missing:
            raise safe_io.InputError(f"{card_path}: no model card next to {model} (--card)",
                                     missing=True) from None
        raise
    if not isinstance(card, dict) or not isinstance(card.get("data", {}), dict):
        raise safe_io.InputError(f"{card_path}: not a model card (expected a JSON object with "
                                 f"a `data` object)")
    sha = hashlib.sha256(safe_io.read_bytes(model, what="an ONNX file (--model)")).hexdigest()
    if card.get("model_sha256", sha) != sha:
        raise SystemExit(f"error: {card_path} describes another file (sha256 "
                         f"{card['model_sha256'][:16]}…) than {model} ({sha[:16]}…): --card "
                         f"would attach these errors to the wrong model")
    m = rdata.read_manifest(root)
    h = rdata.manifest_hash(root)
    own = [str(card["data"].get("manifest_sha256") or ""),
           str((card["data"].get("test_set") or {}).get("manifest_sha256") or "")]
    if any(h in o for o in own):
        raise SystemExit(f"error: {root} is one of the card's own data sets (its test split is "
                         f"on the card already); --card adds further held-out sets")
    train.check_test_set({"settings": {k: card["data"].get(k) for k in ("phase", "albedo")},
                          "clouds": card["data"].get("clouds", [])}, m, root, "--card --data")
    st = m.get("settings", {})
    return {"root": str(root), "manifest_sha256": rdata.manifest_hash(root),
            "seed": st.get("seed"), "eval_samples": st.get("eval_samples"),
            "eval_noise": st.get("eval_noise"), "gpu": st.get("gpu", False),
            "test_clouds": [c.get("split") for c in m.get("clouds", [])].count("test")}, sha


def add_to_card(model: Path, model_sha: str, entry: dict, err: dict) -> None:
    """Records ``err`` (the test split's errors) in the model's card as a further held-out set,
    named by its folder, manifest hash, seed and label settings; the same set (manifest hash)
    replaces its earlier entry in place."""
    card_path = model.with_suffix(".json")
    card = safe_io.load_json(card_path, what="a model card (JSON)")
    # A card written before cards named their file: it describes this one from now on.
    card.setdefault("model_sha256", model_sha)
    new = {**entry, "errors": err}
    sets = card.get("further_test_sets", [])
    same = [i for i, e in enumerate(sets) if e.get("manifest_sha256") == entry["manifest_sha256"]]
    if same:
        sets[same[0]] = new  # in its place: the card's order stays the order sets were added
    else:
        sets.append(new)
    card["further_test_sets"] = sets
    rexport.write_card(model, card)
    print(f"added to {card_path} and {model.with_suffix('.md')}")


if __name__ == "__main__":
    main()
