"""train_sky.py: the sky head on a frozen sun model, its export and its refusals."""

import json

import numpy as np
import pytest
import torch

import train_sky
from rpnn import export
from rpnn.model import DESCRIPTOR_LEN, RPNN


def sky_set(root, trunk, n_train=600, n_val=100, seed=0):
    """A record set with sky columns whose transfer is a linear function of `trunk`'s output
    (what a head can represent exactly), t_00 > 0."""
    rng = np.random.default_rng(seed)
    w = rng.normal(0, 0.05, size=(trunk.sun.width, 25)).astype(np.float32)
    root.mkdir(parents=True, exist_ok=True)
    shards = []
    for split, n in (("train", n_train), ("val", n_val)):
        level = rng.gamma(2.0, 0.5, size=(n, 10, 1))
        x = np.empty((n, DESCRIPTOR_LEN), np.float32)
        x[:, :-1] = (level * rng.uniform(0.9, 1.1, size=(n, 10, 225))).reshape(n, -1)
        x[:, -1] = rng.uniform(0, np.pi, size=n)
        meta = np.zeros((n, 40), np.float32)
        with torch.no_grad():
            o = trunk.trunk(torch.from_numpy(x))[0].numpy()
        meta[:, 15:40] = o @ w
        meta[:, 15] = 0.2 + np.abs(meta[:, 15])
        names = {w: f"{split}_00000_{w}.npy" for w in ("x", "y", "meta")}
        np.save(root / names["x"], x)
        np.save(root / names["y"], np.full(n, 0.1, np.float32))
        np.save(root / names["meta"], meta)
        shards.append({"split": split, "index": 0, "records": n, "converged": n, **names})
    cols = [f"c{i}" for i in range(15)] + [f"sky_sh_{i}" for i in range(25)]
    (root / "manifest.json").write_text(json.dumps({
        "format": "nimbus-rpnn-records/2", "descriptor_len": DESCRIPTOR_LEN,
        "meta_columns": cols, "settings": {"phase": "hg", "albedo": 1.0, "sky_transfer": True},
        "clouds": [{"name": "a", "split": "train"}, {"name": "b", "split": "val"}],
        "shards": shards, "records": n_train + n_val, "converged": n_train + n_val,
        "convergence_rate": 1.0}))
    return root


@pytest.fixture
def sun_model(tmp_path):
    torch.manual_seed(1)
    m = RPNN(width=16).eval()
    with torch.no_grad():
        for p in m.parameters():
            p.uniform_(-0.3, 0.3)
    path = tmp_path / "sun.onnx"
    export.export_onnx(m, path, {"nimbus.rpnn.phase": "hg"})
    return path


def test_head_learns_and_exports_both_heads(tmp_path, sun_model):
    sun = RPNN(width=16)
    export.import_onnx(sun, sun_model)
    data = sky_set(tmp_path / "data", train_sky.SkyRPNN(sun, train_sky.SkyHead(16)))
    out = tmp_path / "sky.onnx"
    r = train_sky.main(["--init", str(sun_model), "--data", str(data), "--run",
                        str(tmp_path / "run"), "--epochs", "200", "--batch", "100", "--lr", "3e-3",
                        "--export", str(out)])
    # The head learns the (representable) transfer: on held-out rows its t_00 error is a
    # fraction of a constant predictor's (the mean label).
    assert r["log"][-1]["val"] < r["log"][0]["val"]
    t = np.load(data / "val_00000_meta.npy")[:, 15]
    const = float(np.median(np.abs(t.mean() - t) / np.abs(t)))
    assert r["val"]["t00_median"] < 0.5 * const, (r["val"], const)
    x = np.load(data / "val_00000_x.npy")[:8]
    y = export.onnx_predict(out, x)
    assert y.shape == (8, 26)
    # The sun column is the sun model's.
    np.testing.assert_allclose(y[:, 0], export.onnx_predict(sun_model, x)[:, 0], rtol=1e-6)
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["config"]["sky_sh_coeffs"] == 25 and card["sun_column_max_relative_change"] < 1e-5


def test_a_set_without_sky_columns_is_refused(tmp_path, sun_model, record_set, capsys):
    with pytest.raises(SystemExit) as e:
        train_sky.main(["--init", str(sun_model), "--data", str(record_set), "--run",
                        str(tmp_path / "run")])
    assert "sky_sh_0" in str(e.value) and "--sky-transfer" in str(e.value)


def test_missing_files_are_named(tmp_path, record_set):
    with pytest.raises(SystemExit) as e:
        train_sky.main(["--init", str(tmp_path / "nope.onnx"), "--data", str(record_set),
                        "--run", str(tmp_path / "run")])
    assert "nope.onnx" in str(e.value)


def test_head_width_and_depth_are_exported(tmp_path, sun_model):
    """`--head-width` / `--head-layers` shape the head's hidden layers (the first reads the
    trunk's 16 features); the export holds them and its card says so; a head of no layers or a
    negative width is refused."""
    sun = RPNN(width=16)
    export.import_onnx(sun, sun_model)
    data = sky_set(tmp_path / "data", train_sky.SkyRPNN(sun, train_sky.SkyHead(16)))
    out = tmp_path / "sky.onnx"
    train_sky.main(["--init", str(sun_model), "--data", str(data), "--run", str(tmp_path / "run"),
                    "--epochs", "2", "--batch", "100", "--head-width", "24", "--head-layers", "4",
                    "--export", str(out)])
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["config"]["sky_head_width"] == 24 and card["config"]["sky_head_layers"] == 4
    import onnx
    shapes = {tuple(i.dims) for i in onnx.load(str(out)).graph.initializer if len(i.dims) == 2}
    # The head: 16 → 24, 24 → 24 twice, 24 → 25 (weights stored either way round).
    for d in ((16, 24), (24, 24), (24, 25)):
        assert d in shapes or d[::-1] in shapes, (d, shapes)
    for bad in (["--head-layers", "0"], ["--head-width", "-1"]):
        with pytest.raises(SystemExit) as e:
            train_sky.main(["--init", str(sun_model), "--data", str(data), "--run",
                            str(tmp_path / "run2"), *bad])
        assert "--head-layers" in str(e.value)


def test_sky_blocks_concatenate_an_earlier_block(tmp_path, sun_model):
    """`--sky-blocks 4,9`: the head's first layer reads block 4's output beside the last's (32
    values for this 16-wide trunk); the export computes the same as torch, keeps the sun column,
    and its card names the blocks; blocks out of range or named twice are refused."""
    sun = RPNN(width=16)
    export.import_onnx(sun, sun_model)
    data = sky_set(tmp_path / "data", train_sky.SkyRPNN(sun, train_sky.SkyHead(16)))
    out = tmp_path / "sky.onnx"
    train_sky.main(["--init", str(sun_model), "--data", str(data), "--run", str(tmp_path / "run"),
                    "--epochs", "2", "--batch", "100", "--sky-blocks", "4,9",
                    "--export", str(out)])
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["config"]["sky_head_blocks"] == [4, 9] and card["onnx_check"]["passed"]
    assert card["sun_column_max_relative_change"] < 1e-5
    import onnx
    g = onnx.load(str(out)).graph
    shapes = {tuple(i.dims) for i in g.initializer if len(i.dims) == 2}
    assert (32, 16) in shapes or (16, 32) in shapes, shapes
    # Concat nodes: the 10 blocks' (Σ^k, γ), the head's input (blocks 4 and 9), the output.
    assert sum(n.op_type == "Concat" for n in g.node) == 12
    for bad in ("4,10", "9,9", "x"):
        with pytest.raises(SystemExit) as e:
            train_sky.main(["--init", str(sun_model), "--data", str(data), "--run",
                            str(tmp_path / "run2"), "--sky-blocks", bad])
        assert "--sky-blocks" in str(e.value)
