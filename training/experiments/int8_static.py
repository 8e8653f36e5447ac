"""Fixed int8 activation scales (static quantization) against the shipped copy's scale per run
(docs/experiments/2026-12-06-rpnn-accuracy-and-speed-on-the-cpu.md, "2026-12-07: fixed
activation scales, not adopted").

The same choices as ``training/quantize.py`` (int8 weights per output channel, u8 activations,
the heads in f32, only MatMul/Gemm layers), but with ONNX Runtime's ``quantize_static`` in QDQ
format, calibrated on records drawn (seed 0) from a set's *training* split, then compared with
the f32 model as ``quantize.py --records`` compares (the set's test split, runs of 1 297).

    python training/experiments/int8_static.py models/rpnn-hg-sky.onnx \
        --calibration out/sky_set --records out/sky_test --method percentile --out /tmp/q.onnx
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import onnx

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import quantize as qz  # noqa: E402
from rpnn import data as rdata  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("--calibration", type=Path, required=True, help="a set with a train split")
    ap.add_argument("--records", type=Path, required=True, help="a set with a test split")
    ap.add_argument("--method", choices=["minmax", "percentile"], default="percentile")
    ap.add_argument("--count", type=int, default=4096, help="calibration records")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    recs = rdata.Records(rdata.load_shards(a.calibration, "train", check=False))
    if len(recs) == 0:
        raise SystemExit(f"{a.calibration}: no training records to calibrate on")
    idx = np.sort(np.random.default_rng(0).choice(len(recs), min(a.count, len(recs)), replace=False))
    x, _ = recs.gather(idx)
    x = np.asarray(x, dtype=np.float32)
    model = onnx.load(str(a.model))
    name = model.graph.input[0].name

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter([{name: x[i : i + 512]} for i in range(0, len(x), 512)])

        def get_next(self):
            return next(self.it, None)

    method = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile}
    t = time.time()
    quantize_static(
        str(a.model),
        str(a.out),
        Reader(),
        quant_format=QuantFormat.QDQ,
        op_types_to_quantize=["MatMul", "Gemm"],
        per_channel=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        nodes_to_exclude=qz.head_layers(model),
        calibrate_method=method[a.method],
    )
    print(f"quantized in {time.time() - t:.1f} s", file=sys.stderr)
    print(json.dumps(qz.compare(a.model, a.out, a.records, 3000, 1297), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
