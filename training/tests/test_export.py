"""ONNX export: onnxruntime agrees with torch; the graph carries the architecture."""

import json

import numpy as np
import onnx
import pytest
import torch

import train
from rpnn import export as rexport
from rpnn.model import DESCRIPTOR_LEN, RPNN


def random_rows(n, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.gamma(1.5, 0.6, size=(n, DESCRIPTOR_LEN)).astype(np.float32)
    x[:, -1] = rng.uniform(0, np.pi, size=n)
    return x


def test_round_trip_paper_configuration(tmp_path):
    torch.manual_seed(0)
    m = RPNN()
    path = tmp_path / "m.onnx"
    rexport.export_onnx(m, path)
    check = rexport.verify(m, path, random_rows(300))
    assert check["passed"], check
    # Dynamic batch axis: 1 row and 7 rows work.
    for n in (1, 7):
        assert rexport.onnx_predict(path, random_rows(n, n)).shape == (n, 1)
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(meta["nimbus.rpnn.config"]) == m.config()


def test_round_trip_three_outputs(tmp_path):
    torch.manual_seed(1)
    m = RPNN(width=24, outputs=3)
    path = tmp_path / "m3.onnx"
    rexport.export_onnx(m, path)
    assert rexport.verify(m, path, random_rows(50))["passed"]


def test_relative_difference_floor():
    b = np.array([1.0, 1.0, 0.0, 1e-4])
    a = b + np.array([1e-6, 0, 1e-6, 1e-6])
    # 0 and 1e-4 are compared against the mean |b| (≈ 0.5): 1e-6 / 0.500025.
    assert abs(rexport.max_relative_difference(a, b) - 1e-6 / np.mean(b)) < 1e-15


def test_train_exports_model_and_card(record_set, tmp_path):
    onnx_path = tmp_path / "models" / "rpnn-test.onnx"
    train.train(train.parse_args([
        "--data", str(record_set), "--run", str(tmp_path / "run"), "--width", "16",
        "--epochs", "2", "--batch", "200", "--device", "cpu", "--quiet",
        "--export", str(onnx_path), "--reproduce", "make it so"]))
    card = json.loads(onnx_path.with_suffix(".json").read_text())
    assert card["export_check"]["passed"] and card["export_check"]["rows"] == 300 + 200
    assert card["data"]["train_records"] == 1200 and card["data"]["test_records"] == 200
    assert len(card["data"]["manifest_sha256"]) == 64
    assert card["architecture"]["parameters"] > 0 and card["architecture"]["layers"] == 23
    assert card["reproduce"] == "make it so"
    md = onnx_path.with_suffix(".md").read_text()
    assert "make it so" in md and "passed" in md


def test_outputs_are_whole_or_absent(tmp_path):
    """A write that fails half-way leaves the previous file and no temporary behind."""
    from rpnn.export import replace_atomically

    target = tmp_path / "model.onnx"
    target.write_bytes(b"old")

    def fails(tmp):
        tmp.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        replace_atomically(target, fails)
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.onnx"]
    replace_atomically(target, lambda t: t.write_bytes(b"new"))
    assert target.read_bytes() == b"new" and len(list(tmp_path.iterdir())) == 1
