"""float16 descriptors (`nimbus datagen --f16`): the reader restores gamma in float32 from the
meta, and the shipped network's predictions on the same records move by < 1e-3 relative."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rpnn import data as rdata
from rpnn import export as rexport

ROOT = Path(__file__).resolve().parents[2]
NIMBUS = Path(os.environ.get("NIMBUS_BIN", ROOT / "target" / "release" / "nimbus"))
MODEL = ROOT / "models" / "rpnn-hg.onnx"


def test_f16_records_predict_like_f32(tmp_path):
    if not NIMBUS.is_file():
        pytest.fail(f"{NIMBUS}: build it first (`cargo build --release`; scripts/test.sh does)")
    args = ["--clouds", "gen:5", "--records", "600", "--val-records", "0", "--test-records",
            "0", "--shard-size", "200", "--samples", "16", "--density-range", "10,300",
            "--light", "uniform-gamma", "--device", "cpu", "-q"]
    for name, extra in (("f32", []), ("f16", ["--f16"])):
        subprocess.run([str(NIMBUS), "datagen", *args, *extra, "--out", str(tmp_path / name)],
                       check=True, capture_output=True, timeout=300)
    a = rdata.Records(rdata.load_shards(tmp_path / "f32", "train"))
    b = rdata.Records(rdata.load_shards(tmp_path / "f16", "train"))
    assert b.shards[0].x.dtype == np.float16 and len(a) == len(b) == 600
    idx = np.arange(600)
    (x32, y32), (x16, y16) = a.gather(idx), b.gather(idx)
    assert np.array_equal(y32, y16)
    # gamma from the meta's float32 directions in float64: the descriptor's own gamma to 1e-6.
    np.testing.assert_allclose(x16[:, -1], x32[:, -1], atol=1e-6)
    p32 = rexport.onnx_predict(MODEL, x32)[:, 0]
    p16 = rexport.onnx_predict(MODEL, x16)[:, 0]
    # Relative to the prediction, floored at 1 % of the mean prediction: records more than 100×
    # darker than the mean (the final ReLU gives some exact zeros) are judged by their absolute
    # change. Seen here: max 4.1e-4 where p > 0.1 × mean, median 3e-5; unfloored, a record at
    # 1/700 of the mean reaches 2.8e-3 relative (3e-7 absolute).
    rel = np.abs(p16 - p32) / np.maximum(np.abs(p32), 0.01 * np.abs(p32).mean())
    assert rel.max() < 1e-3, (rel.max(), np.median(rel))


def test_random_access_advice_keeps_the_rows(tmp_path):
    # Memory-mapped descriptors are advised for random access (no readahead); the rows read
    # back unchanged, and an array that is not memory-mapped is left alone.
    a = np.arange(4 * 2251, dtype=np.float32).reshape(4, 2251)
    np.save(tmp_path / "x.npy", a)
    m = np.load(tmp_path / "x.npy", mmap_mode="r")
    assert getattr(m, "_mmap", None) is not None
    rdata.advise_random(m)
    assert np.array_equal(m[[3, 0, 2]], a[[3, 0, 2]])
    rdata.advise_random(a)  # no mapping: nothing to advise
