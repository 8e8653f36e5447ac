"""ONNX export: onnxruntime agrees with torch; the graph carries the architecture."""

import hashlib
import json

import numpy as np
import onnx
import pytest
import torch

import train
from rpnn import data as rdata
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


def test_import_onnx_restores_the_weights(tmp_path):
    torch.manual_seed(2)
    m = RPNN(width=24)
    path = tmp_path / "m.onnx"
    rexport.export_onnx(m, path)
    torch.manual_seed(3)
    back = RPNN(width=24)
    rexport.import_onnx(back, path)
    # Every parameter, including the bias-free W1 layers the exporter writes transposed under
    # generated names, comes back exactly (float32 copies, no arithmetic).
    for k, v in m.state_dict().items():
        assert torch.equal(v, back.state_dict()[k]), k
    with pytest.raises(ValueError, match="m.onnx.*no weights for|m.onnx.*shape"):
        rexport.import_onnx(RPNN(width=32), path)
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    with pytest.raises(ValueError, match="bad.onnx: not a readable ONNX file"):
        rexport.import_onnx(RPNN(width=24), bad)


def test_fine_tuning_stage_starts_from_the_exported_model(record_set, tmp_path):
    onnx_path = tmp_path / "a.onnx"
    common = ["--data", str(record_set), "--width", "16", "--batch", "200", "--device", "cpu",
              "--quiet", "--select", "last"]
    first = train.train(train.parse_args([*common, "--run", str(tmp_path / "a"), "--epochs", "3",
                                          "--export", str(onnx_path)]))
    same = train.train(train.parse_args([*common, "--run", str(tmp_path / "b"), "--epochs", "1",
                                         "--init", str(onnx_path)]))
    # Epoch 0 of the stage is the imported network on the same validation records with the same
    # loss: the first run's last validation loss up to float32 summation order (seen: equal).
    np.testing.assert_allclose(same["state"]["log"][0]["val_loss"],
                               first["state"]["log"][-1]["val_loss"], rtol=1e-5)
    tuned_path = tmp_path / "c.onnx"
    train.train(train.parse_args([*common, "--run", str(tmp_path / "c"), "--epochs", "1",
                                  "--init", str(onnx_path), "--rel-eps", "0.003",
                                  "--export", str(tuned_path)]))
    card = json.loads(tuned_path.with_suffix(".json").read_text())
    assert card["training"]["rel_eps"] == 0.003 and card["training"]["epochs"] == 1
    assert card["training"]["init"]["path"] == str(onnx_path)
    assert card["training"]["init"]["before"]["epochs"] == 3
    md = tuned_path.with_suffix(".md").read_text()
    assert "Fine-tuned from" in md and "3 epochs" in md and "+ 0.003)²" in md


def test_blend_init_exports_the_interpolated_weights(record_set, tmp_path):
    common = ["--data", str(record_set), "--width", "16", "--batch", "200", "--device", "cpu",
              "--quiet", "--select", "last"]
    start = tmp_path / "start.onnx"
    train.train(train.parse_args([*common, "--run", str(tmp_path / "s"), "--epochs", "2",
                                  "--export", str(start)]))
    blended = tmp_path / "blended.onnx"
    train.train(train.parse_args([*common, "--epochs", "2", "--init", str(start),
                                  "--run", str(tmp_path / "b"), "--export", str(blended),
                                  "--blend-init", "0.25"]))
    w = {"tuned": RPNN(width=16)}
    w["tuned"].load_state_dict(torch.load(tmp_path / "b" / "best.pt", weights_only=False)["model"])
    for name, path in (("start", start), ("blended", blended)):
        w[name] = RPNN(width=16)
        rexport.import_onnx(w[name], path)
    a, b, c = (w[k].state_dict() for k in ("start", "tuned", "blended"))
    moved = 0
    for k in a:
        # 0.75 a + 0.25 b in float32: a few ulps of the larger term.
        np.testing.assert_allclose(c[k], 0.75 * a[k] + 0.25 * b[k], rtol=1e-5, atol=1e-6)
        moved += int(not torch.allclose(a[k], b[k]))
    assert moved > 0  # the fine-tuning changed the weights, so the blend is a real mixture
    card = json.loads(blended.with_suffix(".json").read_text())
    assert card["training"]["blend_init"] == 0.25
    assert "0.75 × the starting weights + 0.25 × the trained ones" in \
        blended.with_suffix(".md").read_text()
    # A starting file replaced since the run began is refused, not blended.
    train.train(train.parse_args([*common, "--run", str(tmp_path / "s"), "--epochs", "3",
                                  "--export", str(start), "--resume"]))
    with pytest.raises(SystemExit, match="no longer the file this run started from"):
        train.train(train.parse_args([*common, "--epochs", "2", "--init", str(start), "--resume",
                                      "--run", str(tmp_path / "b"), "--export", str(blended),
                                      "--blend-init", "0.25"]))
    # Without a starting point there is nothing to blend with; out of range is refused.
    with pytest.raises(SystemExit, match="--blend-init needs a run that started from --init"):
        train.train(train.parse_args([*common, "--run", str(tmp_path / "n"), "--epochs", "1",
                                      "--export", str(tmp_path / "n.onnx"),
                                      "--blend-init", "0.5"]))
    for bad in ("1.5", "-0.1", "nan"):
        with pytest.raises(SystemExit):
            train.parse_args([*common, "--run", str(tmp_path / "x"), "--blend-init", bad])


def test_import_check_refuses_a_real_mismatch(tmp_path, monkeypatch):
    m = RPNN(width=24)
    path = tmp_path / "m.onnx"
    rexport.export_onnx(m, path)
    # A weight imported wrongly moves the outputs by O(1): simulate it by a check that sees
    # 1e-3, refused; 5e-5 (float32 order on near-zero outputs) passes.
    for seen, refused in ((1e-3, True), (5e-5, False)):
        monkeypatch.setattr(rexport, "verify", lambda *a, d=seen: {
            "rows": 64, "max_relative_difference": d, "passed": d < 1e-5})
        if refused:
            with pytest.raises(ValueError, match="m.onnx: imported weights differ"):
                rexport.import_onnx(RPNN(width=24), path)
        else:
            rexport.import_onnx(RPNN(width=24), path)


def small_model(record_set, tmp_path, onnx_path):
    """One epoch of a width-16 network on the synthetic set, exported with its card."""
    train.train(train.parse_args([
        "--data", str(record_set), "--run", str(tmp_path / "run"), "--width", "16",
        "--epochs", "1", "--batch", "200", "--device", "cpu", "--quiet",
        "--export", str(onnx_path)]))


def test_evaluate_reports_the_card_errors_and_the_label_noise(record_set, tmp_path):
    import evaluate
    onnx_path = tmp_path / "m.onnx"
    small_model(record_set, tmp_path, onnx_path)
    # Labels with a known relative noise of 4 %: variance of the mean = (0.04 y)².
    m = json.loads((record_set / "manifest.json").read_text())
    for s in m["shards"]:
        if s["split"] == "test":
            y = np.load(record_set / s["y"])
            meta = np.zeros((len(y), 15), np.float32)
            meta[:, 13] = (0.04 * y) ** 2
            np.save(record_set / s["meta"], meta)
    res = evaluate.main(["--data", str(record_set), "--model", str(onnx_path)])
    card = json.loads(onnx_path.with_suffix(".json").read_text())
    assert res["test"]["median_rel_error"] == pytest.approx(
        card["record_errors"]["test"]["median_rel_error"], rel=1e-5)
    assert res["test"]["label_noise_median"] == pytest.approx(0.04, rel=1e-4)
    # |N(0, 0.04)| has median 0.6745 × 0.04; 200 draws: within ±15 % (≈ 3 standard errors).
    assert res["test"]["noise_floor_median"] == pytest.approx(0.6745 * 0.04, rel=0.15)
    # --split train scores the training records alone (e.g. one reference cloud's records).
    res = evaluate.main(["--data", str(record_set), "--model", str(onnx_path), "--split",
                         "train"])
    assert set(res) == {"model", "data", "training"}
    assert res["training"]["records"] == 1200
    # A split asked for by name but empty, and a missing set: errors that name them.
    with pytest.raises(SystemExit, match="no validation records"):
        evaluate.main(["--data", str(record_set), "--model", str(onnx_path), "--split", "val"])
    with pytest.raises(SystemExit, match="manifest.json: not found"):
        evaluate.main(["--data", str(tmp_path / "none"), "--model", str(onnx_path)])


def test_evaluate_card_adds_further_held_out_sets(record_set, tmp_path):
    import evaluate
    from rpnn.synthetic import write_set
    onnx_path = tmp_path / "m.onnx"
    small_model(record_set, tmp_path, onnx_path)
    own = json.loads(onnx_path.with_suffix(".json").read_text())["record_errors"]

    def further(name, seed, cloud):
        root = write_set(tmp_path / name, 0, 300, seed=seed)
        m = json.loads((root / "manifest.json").read_text())
        m["clouds"] = [cloud]
        m["settings"]["gpu"] = True
        (root / "manifest.json").write_text(json.dumps(m))
        return root

    other = further("other", 4, {"name": "c", "split": "test", "seed": 9})
    res = evaluate.main(["--data", str(other), "--model", str(onnx_path), "--card"])
    assert set(res) == {"model", "data", "test"}  # --card scores the test split alone
    card = json.loads(onnx_path.with_suffix(".json").read_text())
    (entry,) = card["further_test_sets"]
    assert entry["errors"]["median_rel_error"] == res["test"]["median_rel_error"]
    assert (entry["seed"], entry["test_clouds"], entry["gpu"]) == (4, 1, True)
    assert card["record_errors"] == own  # the run's own figures stay
    md = onnx_path.with_suffix(".md").read_text()
    assert "## Per-record error on further held-out sets" in md
    assert (f"test: 300 records, median relative error "
            f"{100 * res['test']['median_rel_error']:.1f} %") in md
    assert "seed 4): 1 held-out clouds" in md and "by the GPU path tracer" in md
    # Another set is added after it; the same set again replaces its entry in place.
    evaluate.main(["--data", str(further("more", 7, {"name": "d", "split": "test", "seed": 11})),
                   "--model", str(onnx_path), "--card"])
    evaluate.main(["--data", str(other), "--model", str(onnx_path), "--card"])
    card = json.loads(onnx_path.with_suffix(".json").read_text())
    assert [e["seed"] for e in card["further_test_sets"]] == [4, 7]
    # A set whose test cloud is a training cloud of the model's set: refused, named.
    shared = further("shared", 5, {"name": "b", "split": "test"})
    with pytest.raises(SystemExit, match=r"test clouds \['b'\] are training clouds"):
        evaluate.main(["--data", str(shared), "--model", str(onnx_path), "--card"])
    with pytest.raises(SystemExit):
        evaluate.main(["--data", str(other), "--model", str(onnx_path), "--card", "--split",
                       "val"])
    assert len(json.loads(onnx_path.with_suffix(".json").read_text())["further_test_sets"]) == 2
    # A card and a model file that no longer belong together: refused, both named.
    assert card["model_sha256"] == hashlib.sha256(onnx_path.read_bytes()).hexdigest()
    assert f"sha256 `{card['model_sha256']}`" in onnx_path.with_suffix(".md").read_text()
    moved = tmp_path / "moved.onnx"
    moved.write_bytes(onnx_path.read_bytes() + b"\0")
    moved.with_suffix(".json").write_text(onnx_path.with_suffix(".json").read_text())
    with pytest.raises(SystemExit, match="moved.json describes another file"):
        evaluate.main(["--data", str(other), "--model", str(moved), "--card"])
    # A model without its card: refused before anything is scored, the card's path named.
    bare = tmp_path / "bare.onnx"
    bare.write_bytes(onnx_path.read_bytes())
    with pytest.raises(SystemExit, match="bare.json: no model card"):
        evaluate.main(["--data", str(other), "--model", str(bare), "--card"])


def test_mean_ratio_by_gamma_is_the_bias_at_that_angle(record_set):
    # A "model" that is the synthetic truth times 1.1 below gamma = 90° and 0.9 above: every
    # 30° bin reports exactly its factor (the bins split at 90°), with a small standard error.
    class Biased(torch.nn.Module):
        def forward(self, x):
            g = x[:, -1]
            y = (0.3 * torch.exp(-x[:, :225].mean(1)) * (1.2 + torch.cos(g))
                 + 0.1 * x[:, 5 * 225:6 * 225].mean(1))
            return (y * torch.where(g < np.pi / 2, 1.1, 0.9))[:, None]

    recs = rdata.Records(rdata.load_shards(record_set, "test"))
    err = train.record_errors(Biased(), train.Batches(recs, np.arange(len(recs)),
                                                      torch.device("cpu"), False), 64)
    assert len(err["by_gamma"]) == 6
    for b in err["by_gamma"]:
        want = 1.1 if b["gamma_deg"][1] <= 90 else 0.9
        # float32 descriptors and targets: the truth is reproduced to ≈ 1e-6 relative.
        assert b["mean_ratio"] == pytest.approx(want, rel=1e-4)
        assert 0 <= b["mean_ratio_se"] < 0.02
    assert any("mean prediction / mean target by gamma" in line
               for line in rexport.record_error_lines({"test": err}))


def test_card_names_the_stage_a_fine_tuning_started_from(tmp_path):
    """A fine-tuning stage started from an exported model's card or from an earlier stage's
    checkpoint: the card line says what that stage was, and never prints unknown fields."""
    onnx_before = {"loss": "rel-l2", "rel_eps": 0.01, "epochs": 20, "steps": 20000,
                   "seconds": 5003.2}
    line = rexport.init_lines({"path": "models/m.onnx", "sha256": "ab" * 32,
                               "before": onnx_before})[0]
    assert "that model: loss rel-l2, ε 0.01, 20 epochs (20000 steps), 5003 s." in line
    # A checkpoint: its run state as train.load_init reads it (no step count).
    model = RPNN(levels=10, width=8, head_layers=1)
    state = {"epoch": 8, "seconds": 270.4, "loss": "rel-l2", "rel_eps": 0.01,
             "init": {"path": "models/rpnn-hg.onnx", "sha256": "cd" * 32}}
    ck = tmp_path / "last.pt"
    torch.save({"model": model.state_dict(), "config": model.config(), "state": state}, ck)
    info = train.load_init(RPNN(levels=10, width=8, head_layers=1), ck)
    line = rexport.init_lines(info)[0]
    assert ("that model: loss rel-l2, ε 0.01, 8 epochs, 270 s, itself started from "
            "`models/rpnn-hg.onnx`.") in line, line
    assert "None" not in line


def test_errors_by_cloud_kind(record_set):
    # The synthetic truth itself as the "model": error 0. The test split's targets of the
    # cirrus cloud are divided by 1.25, so its records read exactly 25 % (ratio 1.25) and the
    # rest 0; a cloud without a kind is named, an index outside the manifest is "unknown".
    class Truth(torch.nn.Module):
        def forward(self, x):
            g = x[:, -1]
            return (0.3 * torch.exp(-x[:, :225].mean(1)) * (1.2 + torch.cos(g))
                    + 0.1 * x[:, 5 * 225:6 * 225].mean(1))[:, None]

    m = json.loads((record_set / "manifest.json").read_text())
    m["clouds"] = [{"name": "a", "split": "train", "kind": "cumulus"},
                   {"name": "b", "split": "test", "kind": "cirrus"},
                   {"name": "c_file", "split": "test"}]
    (record_set / "manifest.json").write_text(json.dumps(m))
    for s in m["shards"]:
        if s["split"] == "test":
            y = np.load(record_set / s["y"])
            meta = np.load(record_set / s["meta"])
            n = len(y)
            meta[:, 0] = np.where(np.arange(n) < n // 2, 1, np.where(np.arange(n) < 3 * n // 4,
                                                                      2, 7))
            y[: n // 2] /= 1.25
            np.save(record_set / s["y"], y)
            np.save(record_set / s["meta"], meta)
    kinds = rdata.cloud_kinds(record_set, "test")
    recs = rdata.Records(rdata.load_shards(record_set, "test"))
    assert len(kinds) == len(recs) == 200
    err = train.record_errors(Truth(), train.Batches(recs, np.arange(len(recs)),
                                                     torch.device("cpu"), False), 64, kinds)
    by = {b["kind"]: b for b in err["by_kind"]}
    assert sorted(by) == ["c_file", "cirrus", "unknown"]
    assert [by[k]["records"] for k in ("cirrus", "c_file", "unknown")] == [100, 50, 50]
    # float32 descriptors and targets: the truth is reproduced to ≈ 1e-6 relative.
    assert by["cirrus"]["median_rel_error"] == pytest.approx(0.25, rel=1e-4)
    assert by["cirrus"]["mean_ratio"] == pytest.approx(1.25, rel=1e-4)
    for k in ("c_file", "unknown"):
        assert by[k]["median_rel_error"] < 1e-4
        assert by[k]["mean_ratio"] == pytest.approx(1.0, rel=1e-4)
    assert any("by cloud kind: c_file 0.0 % (50, mean ratio 1.000), cirrus 25.0 % (100" in line
               for line in rexport.record_error_lines({"test": err}))
    with pytest.raises(ValueError, match="199 cloud kinds for 200 records"):
        train.record_errors(Truth(), train.Batches(recs, np.arange(len(recs)),
                                                   torch.device("cpu"), False), 64, kinds[1:])
