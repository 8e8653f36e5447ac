"""Training end to end on a small synthetic record set, and the data reader's errors."""

import csv
import json

import numpy as np
import pytest

import train
from rpnn import data as rdata
from conftest import write_set


def run(record_set, tmp_path, *extra):
    return train.train(train.parse_args([
        "--data", str(record_set), "--run", str(tmp_path / "run"), "--width", "32",
        "--batch", "100", "--seed", "3", "--device", "cpu", "--quiet", *extra]))


def test_validation_loss_falls(record_set, tmp_path):
    res = run(record_set, tmp_path, "--epochs", "25")
    log = res["state"]["log"]
    first, best = log[0]["val_loss"], res["state"]["best_val"]
    assert log[0]["epoch"] == 0  # the untrained network: a constant at the mean target
    # The synthetic target is a smooth function of three descriptor quantities; 25 epochs of
    # Adam on 900 rows reduce the validation loss at least tenfold below the constant predictor
    # (seen: 38x). A broken gradient path, a dead output ReLU or a wrong level slice stalls
    # well above that.
    assert best < first / 10, (first, best)
    assert log[-1]["test_loss"] is not None
    with open(tmp_path / "run" / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 26 and set(rows[0]) == {"epoch", "train_loss", "val_loss", "test_loss",
                                               "seconds"}
    assert (tmp_path / "run" / "curves.png").stat().st_size > 1000
    assert (tmp_path / "run" / "best.pt").exists()


def test_select_last_keeps_the_last_epoch(record_set, tmp_path):
    import torch
    res = run(record_set, tmp_path, "--epochs", "3", "--select", "last")
    assert res["state"]["best_epoch"] == 3
    assert res["state"]["best_val"] == res["state"]["log"][-1]["val_loss"]
    best = torch.load(tmp_path / "run" / "best.pt", weights_only=False)
    last = torch.load(tmp_path / "run" / "last.pt", weights_only=False)
    assert best["epoch"] == 3
    for k, v in best["model"].items():
        assert torch.equal(v, last["model"][k]), k


def test_resume_continues_and_matches_an_uninterrupted_run(record_set, tmp_path):
    full = run(record_set, tmp_path / "a", "--epochs", "4")
    run(record_set, tmp_path / "b", "--epochs", "2")
    resumed = run(record_set, tmp_path / "b", "--epochs", "4", "--resume")
    a = [r["val_loss"] for r in full["state"]["log"]]
    b = [r["val_loss"] for r in resumed["state"]["log"]]
    assert len(b) == 5  # epochs 0..4
    # Same seeds, same minibatch order: the resumed run is the same computation (up to the
    # nondeterminism of multithreaded CPU kernels, far below 1e-4 relative).
    np.testing.assert_allclose(b, a, rtol=1e-4)


def test_split_is_75_25_and_fixed():
    fit, val = rdata.split_indices(1000, 0.25, 7)
    assert len(fit) == 750 and len(val) == 250
    assert not set(fit) & set(val)
    fit2, val2 = rdata.split_indices(1000, 0.25, 7)
    assert np.array_equal(val, val2)


def test_gather_reads_rows_across_shards(record_set):
    recs = rdata.Records(rdata.load_shards(record_set, "train"))
    assert len(recs) == 1200
    idx = np.array([1199, 0, 150, 99, 100, 150])
    x, y = recs.gather(idx)
    full_x = np.concatenate([s.x for s in recs.shards])
    np.testing.assert_array_equal(x, full_x[idx])


def test_missing_manifest_names_the_file(tmp_path):
    with pytest.raises(rdata.DataError, match="manifest.json: not found"):
        rdata.read_manifest(tmp_path)


def test_wrong_descriptor_length_names_the_field(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    m = json.loads((root / "manifest.json").read_text())
    m["descriptor_len"] = 99
    (root / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(rdata.DataError, match="descriptor_len"):
        rdata.read_manifest(root)


def test_nan_target_names_the_file_and_row(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    y = np.load(root / "train_00000_y.npy")
    y[4] = np.nan
    np.save(root / "train_00000_y.npy", y)
    with pytest.raises(rdata.DataError, match=r"train_00000_y.npy: row 4"):
        rdata.load_shards(root, "train")


def test_truncated_shard_is_refused(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    (root / "train_00000_x.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(rdata.DataError, match="train_00000_x.npy"):
        rdata.load_shards(root, "train")


def test_axis_turns_train_and_are_checked(record_set, tmp_path):
    # 90° covers every row: each is turned by a random number of quarter turns; the run trains
    # (finite, falling loss) and differs from the run without turns; out of range is refused.
    plain = run(record_set, tmp_path / "a", "--epochs", "2")
    turned = run(record_set, tmp_path / "b", "--epochs", "2", "--axis-turns", "90")
    a = [r["val_loss"] for r in plain["state"]["log"]]
    b = [r["val_loss"] for r in turned["state"]["log"]]
    assert a[0] == b[0]  # the untrained network is the same
    assert np.isfinite(b).all() and b[-1] < b[0] and b[-1] != a[-1], (a, b)
    with pytest.raises(SystemExit):
        run(record_set, tmp_path / "c", "--epochs", "1", "--axis-turns", "91")


def test_resume_refuses_another_loss(record_set, tmp_path):
    run(record_set, tmp_path, "--epochs", "1")
    with pytest.raises(SystemExit, match="rel-eps 0.01; resuming with --loss rel-l2 --rel-eps 0.002"):
        run(record_set, tmp_path, "--epochs", "2", "--resume", "--rel-eps", "0.002")


def test_ema_update_is_the_moving_average():
    import torch
    torch.manual_seed(0)
    ema, model = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    e0 = [p.detach().clone() for p in ema.parameters()]
    m = [p.detach().clone() for p in model.parameters()]
    # Step 0: the warm-up caps the decay at (1 + 0) / (10 + 0) = 0.1.
    train.ema_update(ema, model, 0.999, 0)
    for pe, a, b in zip(ema.parameters(), e0, m):
        torch.testing.assert_close(pe.detach(), 0.1 * a + 0.9 * b)
    # Late steps use the decay itself.
    e1 = [p.detach().clone() for p in ema.parameters()]
    train.ema_update(ema, model, 0.9, 10_000)
    for pe, a, b in zip(ema.parameters(), e1, m):
        torch.testing.assert_close(pe.detach(), 0.9 * a + 0.1 * b)


def test_ema_is_kept_exported_and_resumes(record_set, tmp_path):
    import torch
    full = run(record_set, tmp_path / "a", "--epochs", "3", "--ema", "0.95", "--select", "last")
    best = torch.load(tmp_path / "a" / "run" / "best.pt", weights_only=False)
    last = torch.load(tmp_path / "a" / "run" / "last.pt", weights_only=False)
    # best.pt (what is exported) holds the average, last.pt the trained weights and the average.
    for k, v in best["model"].items():
        assert torch.equal(v, last["ema"][k]), k
    assert any(not torch.equal(v, last["model"][k]) for k, v in best["model"].items())
    assert full["state"]["ema_steps"] == 3 * 9  # 900 fitting rows in minibatches of 100
    # Interrupted after epoch 1 and resumed: the same computation (see the test above).
    run(record_set, tmp_path / "b", "--epochs", "1", "--ema", "0.95", "--select", "last")
    resumed = run(record_set, tmp_path / "b", "--epochs", "3", "--ema", "0.95", "--select",
                  "last", "--resume")
    np.testing.assert_allclose([r["val_loss"] for r in resumed["state"]["log"]],
                               [r["val_loss"] for r in full["state"]["log"]], rtol=1e-4)
    with pytest.raises(SystemExit, match="--ema 0.95; resuming with --ema 0.0"):
        run(record_set, tmp_path / "b", "--epochs", "4", "--resume")


def _set_clouds(root, clouds, **settings):
    m = json.loads((root / "manifest.json").read_text())
    m["clouds"] = clouds
    m["settings"].update(settings)
    (root / "manifest.json").write_text(json.dumps(m))


def test_test_data_takes_the_test_split_of_another_set(record_set, tmp_path):
    other = write_set(tmp_path / "other", 0, 300, seed=5)
    cloud = {"source": "Generated", "kind": "cumulus", "resolution": [8, 8, 8]}
    _set_clouds(record_set, [{**cloud, "name": "a", "split": "train", "seed": 1,
                              "density_scale": 10.0},
                             {**cloud, "name": "b", "split": "test", "seed": 2}])
    _set_clouds(other, [{**cloud, "name": "c", "split": "test", "seed": 3}], eval_samples=64,
                eval_noise=0.05)
    res = run(record_set, tmp_path, "--epochs", "1", "--test-data", str(other),
              "--export", str(tmp_path / "m.onnx"))
    assert res["test"] == 300  # the other set's test records, not --data's 200
    card = res["card"]
    assert card["data"]["test_set"]["eval_noise"] == 0.05
    assert card["data"]["test_clouds"] == 1
    assert card["record_errors"]["test"]["records"] == 300
    md = (tmp_path / "m.md").read_text()
    assert "relative standard error of 0.05" in md and str(other) in md
    # A training cloud among the test clouds (same shape, another density scale) is refused,
    # and so is another phase function.
    _set_clouds(other, [{**cloud, "name": "c", "split": "test", "seed": 1,
                         "density_scale": 99.0}])
    with pytest.raises(SystemExit, match=r"test clouds \['c'\] are training clouds"):
        run(record_set, tmp_path / "b", "--epochs", "1", "--test-data", str(other))
    _set_clouds(other, [{**cloud, "name": "c", "split": "test", "seed": 3}], phase="mie")
    with pytest.raises(SystemExit, match="its phase is mie, the training set's hg"):
        run(record_set, tmp_path / "c", "--epochs", "1", "--test-data", str(other))


def test_several_sets_train_together(record_set, tmp_path):
    second = write_set(tmp_path / "second", 500, 0, seed=9)
    # Labels of 1 024 samples in the first set and 4 096 in the second: the card says both.
    for root, n in ((record_set, 1024), (second, 4096)):
        m = json.loads((root / "manifest.json").read_text())
        m["settings"]["samples"] = n
        (root / "manifest.json").write_text(json.dumps(m))
    res = run(record_set, tmp_path, "--epochs", "1", "--data", str(record_set), str(second),
              "--export", str(tmp_path / "m.onnx"))
    assert res["card"]["data"]["samples"] == [1024, 4096]
    assert ("- Labels: training 1024 / 4096 samples each (per set, in the order above; fixed "
            "count") in (tmp_path / "m.md").read_text()
    # 1 700 training rows, no validation split in either: 25 % of them validate.
    assert res["fit"] + res["val"] == 1700
    assert res["card"]["data"]["root"] == f"{record_set}, {second}"
    assert len(res["card"]["data"]["manifest_sha256"].split(", ")) == 2
    _set_clouds(second, [{"name": "z", "split": "train"}], phase="mie")
    with pytest.raises(SystemExit, match="its phase is mie"):
        run(record_set, tmp_path / "b", "--epochs", "1", "--data", str(record_set), str(second))
