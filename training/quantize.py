"""Int8 copy of an exported RPNN for ONNX Runtime on the CPU (beyond the paper).

    python training/quantize.py models/rpnn-hg-sky.onnx [--records out/sky_test]

writes ``models/rpnn-hg-sky.int8.onnx`` next to the model: ONNX Runtime's dynamic quantization
(``onnxruntime.quantization.quantize_dynamic``) of every fully connected layer of the residual
blocks — weights int8 per output channel, each layer's input activations u8 with one scale per
batch, computed at run time — while the output heads stay f32 (quantizing them too doubled the
difference to the f32 model: models/int8.md). ``nimbus render --backend
ort-int8`` runs it; the file records the sha256 of the model it was made from
(``nimbus.rpnn.int8_of``), and the renderer refuses a copy of another model.

With ``--records DIR`` (a ``nimbus datagen`` set) it compares both files on the set's
records, batch by batch as a renderer asks (the scale of a batch's activations depends on
the batch), and writes ``<model>.int8.json``: the relative difference of the sun output and of
the sky head's t_00 to the f32 model (median, 95th percentile, mean ratio), and the per-record
error of both against the labels.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx

sys.path.insert(0, str(Path(__file__).resolve().parent))

from rpnn import safe_io  # noqa: E402

INT8_OF = "nimbus.rpnn.int8_of"
INT8_HOW = "nimbus.rpnn.int8"
HOW = "dynamic: int8 weights per output channel, u8 activations per batch; heads in f32"


def int8_path(model: Path) -> Path:
    """``x.onnx`` -> ``x.int8.onnx`` (``nimbus_rpnn::ort_backend::int8_path_for``)."""
    return model.with_name(model.stem + ".int8.onnx")


def sha256(path: Path) -> str:
    return hashlib.sha256(safe_io.read_bytes(path, what="an ONNX model")).hexdigest()


def head_layers(model: onnx.ModelProto) -> list[str]:
    """The fully connected layers of the output heads (kept in f32), by node name: the
    exporter names them ``/head…`` (sun head ``/head.i/Gemm``, sky head ``/head/layers.i/Gemm``)."""
    names = [
        n.name
        for n in model.graph.node
        if n.op_type in ("Gemm", "MatMul") and n.name.startswith("/head")
    ]
    # quantize_dynamic turns a Gemm into a MatMul (+ Add) named `<gemm>_MatMul` first.
    return names + [n + "_MatMul" for n in names]


def quantize(src: Path, dst: Path | None = None) -> Path:
    """Writes the int8 copy of `src` (default: next to it) and returns its path."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    dst = dst or int8_path(src)
    data = safe_io.read_bytes(src, what="an ONNX model")
    try:
        model = onnx.load_from_string(data)
    except Exception as e:  # noqa: BLE001 - any unreadable file gets the same message
        raise SystemExit(f"{src}: not an ONNX model ({e})")
    heads = head_layers(model)
    if not heads:
        raise SystemExit(f"{src}: no output head (nodes named /head…): not an RPNN export")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "q.onnx"
        quantize_dynamic(
            onnx.load_from_string(data),  # the bytes read and checked above, not the path again
            str(out),
            weight_type=QuantType.QInt8,
            per_channel=True,
            nodes_to_exclude=heads,
        )
        q = onnx.load_from_string(safe_io.read_bytes(out, what="an ONNX model"))
    meta = {p.key: p.value for p in model.metadata_props}
    meta[INT8_OF] = hashlib.sha256(data).hexdigest()
    meta[INT8_HOW] = HOW
    del q.metadata_props[:]
    for k, v in sorted(meta.items()):
        q.metadata_props.add(key=k, value=v)
    # Whole or absent, and never written through a pipe or link left at the path.
    from rpnn.export import replace_atomically

    replace_atomically(dst, lambda t: onnx.save(q, str(t), format="protobuf"))
    return dst


def replace_atomically_json(path: Path, value) -> None:
    from rpnn.export import replace_atomically

    replace_atomically(path, lambda t: t.write_text(json.dumps(value, indent=2) + "\n"))


def session(path: Path, threads: int = 2):
    import onnxruntime as ort

    o = ort.SessionOptions()
    o.intra_op_num_threads = threads
    return ort.InferenceSession(safe_io.read_bytes(path, what="an ONNX model"), o,
                                providers=["CPUExecutionProvider"])


def predict(sess, x: np.ndarray, batch: int) -> np.ndarray:
    name = sess.get_inputs()[0].name
    out = [
        sess.run(None, {name: np.ascontiguousarray(x[i : i + batch], dtype=np.float32)})[0]
        for i in range(0, len(x), batch)
    ]
    return np.concatenate(out)


def compare(src: Path, dst: Path, records: Path, n: int, batch: int) -> dict:
    """Both models on the first `n` records of the set's test split, else its validation split
    (never training records), `batch` rows per run."""
    from rpnn import data as rdata

    for split in ("test", "val"):
        shards = rdata.load_shards(records, split, check=False)
        if shards and sum(len(s.y) for s in shards) > 0:
            break
    else:
        raise SystemExit(f"{records}: no test or validation records to compare on")
    identity = rdata.set_identity(records)
    recs = rdata.Records(shards)
    x, y = recs.gather(np.arange(min(n, len(recs))))
    x = np.asarray(x, dtype=np.float32)
    y = np.asarray(y, dtype=np.float64).reshape(len(x), -1)
    a = predict(session(src), x, batch)
    b = predict(session(dst), x, batch)

    def diff(col: int) -> dict:
        r = np.abs(b[:, col] / np.where(a[:, col] == 0, np.nan, a[:, col]) - 1)
        r = r[np.isfinite(r)]
        if r.size == 0:
            raise SystemExit(f"{src}: output column {col} is 0 on every record compared")
        return {
            "median": float(np.median(r)),
            "p95": float(np.percentile(r, 95)),
            "mean_ratio": float(b[:, col].mean() / a[:, col].mean()),
        }

    t = y[:, 0]
    keep = t > 0
    err = lambda p: float(np.median(np.abs(p[keep, 0] / t[keep] - 1)))  # noqa: E731
    out = {
        "records": str(records),
        "set_identity": identity,
        "split": split,
        "rows": int(len(x)),
        "batch": min(batch, len(x)),
        "sun": diff(0),
        "error_against_labels": {"f32": err(a), "int8": err(b)},
    }
    if a.shape[1] > 1:
        out["sky_t00"] = diff(1)
    return out


def main(argv=None) -> int:
    # A set or file that cannot be used (the message names it): one line, exit status 2.
    with safe_io.reporting_input_errors():
        return _main(argv)


def _main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path, help="an exported RPNN (.onnx)")
    ap.add_argument("-o", "--out", type=Path, help="default: <model>.int8.onnx beside it")
    ap.add_argument("--records", type=Path, help="a datagen set to compare both models on")
    ap.add_argument("--rows", type=int, default=3000, help="records compared (also one batch)")
    ap.add_argument("--batch", type=int, default=2048, help="rows per run (a render's sample)")
    a = ap.parse_args(argv)
    try:
        safe_io.check_regular(a.model, what="an ONNX model")
    except safe_io.InputError as e:
        if e.missing:
            raise safe_io.InputError(f"{a.model}: no such model", missing=True) from None
        raise
    if a.rows < 1 or a.batch < 1:
        raise SystemExit(f"--rows {a.rows} and --batch {a.batch} must be at least 1")
    dst = quantize(a.model, a.out)
    print(f"wrote {dst} ({dst.stat().st_size} bytes, from sha256 {sha256(a.model)[:8]}…)")
    if a.records:
        report = {"model": a.model.name, "int8": dst.name, "how": HOW}
        # The requested batch, and all compared records in one batch (a large render's).
        for batch in sorted({min(a.batch, a.rows), a.rows}):
            c = compare(a.model, dst, a.records, a.rows, batch)
            report[f"batch_{c['batch']}"] = c
        js = dst.with_suffix(".json")
        replace_atomically_json(js, report)
        print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
