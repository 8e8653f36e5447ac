"""ONNX export of a trained RPNN, its onnxruntime check, and the model card.

The graph has one input ``descriptor`` (float32 [N, 2251], layout in rpnn/model.py: raw densities
relative to the cloud's mean extinction, level-major, then gamma in radians; N is a dynamic axis)
and one output ``radiance`` (float32 [N, outputs]): indirect in-scattered radiance per unit sun
irradiance. The architecture is stored in the model's metadata (``nimbus.rpnn.config``) so readers
can refuse a graph that is not an RPNN.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import torch

from . import safe_io

INPUT_NAME = "descriptor"
OUTPUT_NAME = "radiance"
OPSET = 17
# Relative differences are taken against max(|torch output|, mean |torch output|): float32
# rounding through 23 layers is relative to the size of the activations, so an output much smaller
# than the typical one (a near-cancellation, or a ReLU output of exactly 0) carries an error that
# is relative to the typical output, not to itself.


def replace_atomically(path: Path, write) -> None:
    """Calls ``write(tmp)`` for a hidden temporary beside ``path``, syncs it and renames it to
    ``path``: the file is whole or absent (a failed or interrupted write leaves the old one)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def export_onnx(model: torch.nn.Module, path: Path, extra_metadata: dict | None = None) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_atomically(path, lambda tmp: _export_onnx(model, tmp, extra_metadata))


def _export_onnx(model: torch.nn.Module, path: Path, extra_metadata: dict | None) -> None:
    import onnx

    model = model.eval().cpu()
    dummy = torch.zeros(2, model.input_len)
    with warnings.catch_warnings():
        # The TorchScript exporter gives a plain graph of MatMul/Gemm, Add, Relu, Slice and
        # Concat nodes with the parameters as named initializers, which is what Nimbus' own
        # ONNX reader (the WGSL backend) parses.
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            model,
            (dummy,),
            str(path),
            input_names=[INPUT_NAME],
            output_names=[OUTPUT_NAME],
            dynamic_axes={INPUT_NAME: {0: "batch"}, OUTPUT_NAME: {0: "batch"}},
            opset_version=OPSET,
            do_constant_folding=True,
            dynamo=False,
        )
    m = onnx.load_from_string(safe_io.read_bytes(path, what="an ONNX model"))
    meta = {"nimbus.rpnn.config": json.dumps(model.config())}
    meta.update({k: json.dumps(v) if not isinstance(v, str) else v for k, v in (extra_metadata or {}).items()})
    for k, v in meta.items():
        entry = m.metadata_props.add()
        entry.key, entry.value = k, v
    m.producer_name = "nimbus-training"
    onnx.checker.check_model(m)
    onnx.save(m, str(path))


def onnx_predict(path: Path, x: np.ndarray, data: bytes | None = None) -> np.ndarray:
    """onnxruntime's output for rows ``x``: of the model ``data`` (its bytes, already read) or
    else of the file at ``path`` (read through :mod:`rpnn.safe_io`)."""
    import onnxruntime as ort

    if data is None:
        data = safe_io.read_bytes(path, what="an ONNX model")
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    sess = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
    return sess.run([OUTPUT_NAME], {INPUT_NAME: np.ascontiguousarray(x, dtype=np.float32)})[0]


def max_relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max(|b|, mean |b|) over all entries (b: the reference)."""
    if not a.size:
        return 0.0
    floor = max(float(np.mean(np.abs(b))), 1e-30)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), floor)))


def verify(model: torch.nn.Module, path: Path, x: np.ndarray, data: bytes | None = None) -> dict:
    """Runs torch and onnxruntime on the same rows; returns the comparison. ``data``: the ONNX
    file's bytes when already read."""
    model = model.eval().cpu()
    with torch.no_grad():
        ref = model(torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))).numpy()
    got = onnx_predict(path, x, data)
    if got.shape != ref.shape:
        raise RuntimeError(f"{path}: onnxruntime output shape {got.shape} != torch {ref.shape}")
    d = max_relative_difference(got, ref)
    return {"rows": int(len(x)), "max_relative_difference": d, "passed": bool(d < 1e-5)}


def import_onnx(model: torch.nn.Module, path: Path, data: bytes | None = None) -> None:
    """Loads the weights of an ONNX file written by :func:`export_onnx` into ``model`` (same
    architecture): initialisers named like the state dict are copied; the bias-free W1 layers,
    which the exporter writes as a MatMul with the transposed weight under a generated name,
    are found through their node (``/blocks.K/W1/MatMul``). Checked against onnxruntime on
    random rows; raises ``ValueError`` naming the file on any mismatch (``safe_io.InputError``
    when the file cannot be read). ``data``: the file's bytes when already read."""
    import re

    import onnx
    from onnx import numpy_helper

    path = Path(path)
    if data is None:
        data = safe_io.read_bytes(path, what="an ONNX model")
    try:
        graph = onnx.load_from_string(data).graph
    except Exception as e:  # noqa: BLE001 - any parse failure is reported with the file
        raise ValueError(f"{path}: not a readable ONNX file ({e})") from None
    inits = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    state = model.state_dict()
    weights = {k: v for k, v in inits.items() if k in state}
    for node in graph.node:
        m = re.fullmatch(r"/blocks\.(\d+)/W1/MatMul", node.name)
        if node.op_type == "MatMul" and m and node.input[1] in inits:
            weights[f"blocks.{m.group(1)}.W1.weight"] = inits[node.input[1]].T
    missing = sorted(set(state) - set(weights))
    if missing:
        raise ValueError(f"{path}: no weights for {', '.join(missing[:4])}"
                         f"{' …' if len(missing) > 4 else ''} (another architecture?)")
    for k, v in weights.items():
        if tuple(v.shape) != tuple(state[k].shape):
            raise ValueError(f"{path}: `{k}` has shape {tuple(v.shape)}, the model "
                             f"{tuple(state[k].shape)}")
    model.load_state_dict({k: torch.from_numpy(np.array(v, dtype=np.float32)) for k, v in
                           weights.items()})
    x = np.random.default_rng(0).random((64, model.input_len), dtype=np.float32)
    check = verify(model, path, x, data)
    # Random rows are no cloud's descriptor: the network's outputs there are near 0 (0 … 0.01
    # against ≈ 0.05 on real records), left by cancellation, where fp32 summation order alone
    # moves them by up to ≈ 2e-5 relative (seen on a weight-space blend); a weight imported
    # wrongly moves them by O(1). The export check (`verify` on real records) keeps 1e-5.
    if check["max_relative_difference"] >= 1e-4:
        raise ValueError(f"{path}: imported weights differ from onnxruntime by "
                         f"{check['max_relative_difference']:.2e}")


def record_error_lines(errors: dict | None) -> list[str]:
    """Markdown for the per-record errors on the precise splits (train.record_errors)."""
    if not errors:
        return []
    out = ["## Per-record error (precise labels)", ""]
    for name, e in errors.items():
        if not e:
            continue
        out.append(f"- {name}: {e['records']} records, median relative error "
                   f"{100 * e['median_rel_error']:.1f} %, mean prediction / mean target "
                   f"{e['mean_ratio']:.3f}")
        out.append("  - by gamma (180° = front-lit): " + ", ".join(
            f"{b['gamma_deg'][0]}–{b['gamma_deg'][1]}°: {100 * b['median_rel_error']:.1f} % "
            f"({b['records']})" for b in e["by_gamma"]))
        if all("mean_ratio" in b for b in e["by_gamma"]):
            out.append("  - mean prediction / mean target by gamma: " + ", ".join(
                f"{b['gamma_deg'][0]}–{b['gamma_deg'][1]}°: {b['mean_ratio']:.3f} ± "
                f"{b['mean_ratio_se']:.3f}" for b in e["by_gamma"]))
        out.append("  - by target tercile: " + ", ".join(
            f"{b['target'][0]:.3g}–{b['target'][1]:.3g}: {100 * b['median_rel_error']:.1f} %"
            for b in e["by_target"]))
        if e.get("by_kind"):
            out.append("  - by cloud kind: " + ", ".join(
                f"{b['kind']} {100 * b['median_rel_error']:.1f} % ({b['records']}, mean ratio "
                f"{b['mean_ratio']:.3f})" for b in e["by_kind"]))
        if e.get("label_noise_median") is not None:
            out.append(f"  - the labels' own relative noise: median "
                       f"{100 * e['label_noise_median']:.1f} %; a perfect model would read "
                       f"{100 * e['noise_floor_median']:.1f} % (not subtracted above)")
    out.append("")
    return out


def further_test_set_lines(sets: list | None) -> list[str]:
    """The card's section on held-out sets scored after training (``evaluate.py --card``)."""
    if not sets:
        return []
    out = ["## Per-record error on further held-out sets (`evaluate.py --card`)", ""]
    for ts in sets:
        out.extend(test_set_lines(ts, "none of them a training cloud of this stage's set "
                                      "(checked)"))
        out.extend("  " + line for line in record_error_lines({"test": ts["errors"]})[2:]
                   if line.strip())
    out.append("")
    return out


def test_set_lines(ts: dict | None, held_out: str = "none of them a training cloud") -> list[str]:
    """The card's line on a separate test set (``train.py --test-data``; none without one)."""
    if not ts:
        return []
    labels = (f"a pilot of {ts.get('eval_samples')} samples sets how many fresh samples reach a "
              f"relative standard error of {ts['eval_noise']:g} (capped), the label is their "
              f"mean (unbiased)" if ts.get("eval_noise") else
              f"{ts.get('eval_samples') or 'converged'} samples each")
    if ts.get("gpu"):
        labels += ", by the GPU path tracer"
    return [f"- Test records from `{ts['root']}` (manifest sha256 `{ts['manifest_sha256']}`, "
            f"seed {ts.get('seed')}): {ts.get('test_clouds')} held-out clouds, {held_out}; "
            f"labels: {labels}."]


def init_lines(init: dict | None) -> list[str]:
    """The card's line on a fine-tuning stage's starting weights (none without one)."""
    if not init:
        return []
    b = init.get("before") or {}
    before = ""
    if b.get("epochs") is not None:
        eps = f", ε {b['rel_eps']:g}" if b.get("rel_eps") is not None else ""
        loss = f"loss {b['loss']}{eps}, " if b.get("loss") else ""
        steps = f" ({b['steps']} steps)" if b.get("steps") is not None else ""
        start = ((b.get("init") or {}).get("path"))
        start = f", itself started from `{start}`" if start else ""
        before = (f"; that model: {loss}{b['epochs']} epochs{steps}, "
                  f"{b.get('seconds') or 0:.0f} s{start}")
    return [f"- Fine-tuned from `{init['path']}` (sha256 {init['sha256'][:16]}…): its weights, "
            f"a fresh Adam and step-size schedule; epochs, steps and seconds above are this "
            f"stage's{before}."]


def samples_text(samples) -> str:
    """A card's training-label sample count: one number, or one per set (`train.py --data A
    B` with sets of different counts)."""
    return " / ".join(map(str, samples)) if isinstance(samples, list) else str(samples)


def write_card(path_onnx: Path, card: dict) -> tuple[Path, Path]:
    """Writes ``<model>.json`` and ``<model>.md`` next to the ONNX file."""
    path_onnx = Path(path_onnx)
    pj = path_onnx.with_suffix(".json")
    pm = path_onnx.with_suffix(".md")
    replace_atomically(pj, lambda t: t.write_text(json.dumps(card, indent=2) + "\n"))
    a, d, t, e = card["architecture"], card["data"], card["training"], card["export_check"]
    lines = [
        f"# Model card: `{path_onnx.name}`",
        "",
        "Radiance-predicting neural network (Kallweit et al. 2017, §4.3) for Nimbus' RPNN estimator.",
        "",
        "## Architecture",
        f"- {a['levels']} residual blocks (stencil level k and gamma into block k), "
        f"{a['head_layers']} fully connected ReLU layers, width {a['width']}, "
        f"{a['outputs']} output(s); {a['layers']} layers, {a['parameters']:,} parameters.",
        f"- Input `{INPUT_NAME}`: float32 [N, {a['input_len']}], level-major densities relative to the "
        "cloud's mean extinction, then gamma (radians); no further normalisation.",
        f"- Output `{OUTPUT_NAME}`: float32 [N, {a['outputs']}], indirect in-scattered radiance per unit "
        "sun irradiance.",
        "",
        "## Data",
        f"- Set: `{d['root']}` (manifest sha256 `{d['manifest_sha256']}`), phase function "
        f"{d['phase']}, albedo {d['albedo']}.",
        f"- Clouds: {d['train_clouds']} training clouds, {d.get('val_clouds', 0)} validation "
        f"clouds, {d['test_clouds']} held-out test clouds.",
        f"- Records: {d['train_records']} training-cloud records ({t['train_rows']} fitted), "
        f"{d.get('val_records', 0) or t['val_rows']} validation records, {d['test_records']} "
        f"test-cloud records.",
        "- Labels: " + (
            f"training {samples_text(d['samples'])} samples each ("
            f"{'per set, in the order above; ' if isinstance(d['samples'], list) else ''}"
            f"fixed count, unbiased, noisy); validation "
            f"and test {d.get('eval_samples') or 'converged to ±2 % (95 %)'} samples each; "
            f"light directions {d.get('light')}."
            if d.get("samples") else
            f"converged to ±2 % (95 %) where possible: {100 * (d['convergence_rate'] or 0):.0f} %."),
        "",
        "## Training",
        f"- Loss {t.get('loss', 'log')} ("
        + (f"relative L2 (ŷ − y)² / (sg(|ŷ|) + {t.get('rel_eps', 0.01):g})², unbiased under label "
           "noise"
           if t.get("loss") == "rel-l2" else "(log(1 + ŷ) − log(1 + y))², Kallweit §5.2")
        + f"), Adam, step size {t['lr']} ({t.get('schedule', 'constant')}), minibatch "
        f"{t['batch']}, {t['epochs']} epochs ({t.get('steps', '?')} steps), mirror augmentation "
        f"{'on' if t.get('mirror') else 'off'}"
        + (f", quarter turns about the light axis within {t['axis_turns_deg']:g}° of γ = 0 and 180°"
           if t.get("axis_turns_deg") else "")
        + (f", the exported weights a moving average over the steps (decay {t['ema']:g} per step)"
           if t.get("ema") else "")
        + f", seed {t['seed']}, device {t['device']}, "
        f"{t['seconds']:.0f} s.",
        *init_lines(t.get("init")),
        *([f"- Exported weights: {1 - t['blend_init']:g} × the starting weights + "
           f"{t['blend_init']:g} × the trained ones (`--blend-init`, WiSE-FT); the losses below "
           f"are the trained weights', the per-record errors the exported ones'."]
          if t.get("blend_init", 1.0) < 1.0 else []),
        (f"- Exported: the last epoch (`--select last`), validation loss "
         f"{t['best_val_loss']:.4g} (epoch {t['best_epoch']}); "
         if t.get("select") == "last" else
         f"- Best validation loss {t['best_val_loss']:.4g} (epoch {t['best_epoch']}); ")
        + f"test-cloud loss {t['test_loss'] if t['test_loss'] is None else format(t['test_loss'], '.4g')}.",
        *test_set_lines(d.get("test_set")),
        "",
        *record_error_lines(card.get("record_errors")),
        *further_test_set_lines(card.get("further_test_sets")),
        "## Export check",
        f"- onnxruntime vs torch on {e['rows']} real records: max relative difference "
        f"{e['max_relative_difference']:.2e} ({'passed' if e['passed'] else 'FAILED'}, bound 1e-5).",
        *([f"- `{path_onnx.name}` sha256 `{card['model_sha256']}`."]
          if card.get("model_sha256") else []),
        "",
        "## Reproduce",
        "```",
        card["reproduce"],
        "```",
        "",
    ]
    replace_atomically(pm, lambda t: t.write_text("\n".join(lines)))
    return pj, pm
