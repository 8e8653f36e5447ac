"""Bad inputs to train.py and evaluate.py (found by a sweep of ~265 cases): each is a clear error
naming the file or flag, never a traceback or a silently wrong model."""

import json

import numpy as np
import pytest

import evaluate
import train
from conftest import write_set
from rpnn import data as rdata


def run(record_set, run_dir, *extra):
    return train.train(train.parse_args([
        "--data", str(record_set), "--run", str(run_dir), "--width", "16",
        "--batch", "100", "--seed", "3", "--device", "cpu", "--quiet", *extra]))


def set_manifest(root, edit):
    m = json.loads((root / "manifest.json").read_text())
    edit(m)
    (root / "manifest.json").write_text(json.dumps(m))
    return root


@pytest.mark.parametrize("edit,match", [
    (lambda m: m.clear() or m.update({"x": 1}), "format"),
    (lambda m: m["shards"].__setitem__(0, "train_00000_x.npy"), r"shards\[0\] is not an object"),
    (lambda m: m["shards"][0].__setitem__("x", None), r"shards\[0\].x is None"),
    (lambda m: m["shards"][0].__setitem__("x", "/etc/passwd"), "a file name in the set's folder"),
    (lambda m: m["shards"][0].__setitem__("x", "."), "a file name in the set's folder"),
    (lambda m: m["shards"][0].__setitem__("records", "100"), r"shards\[0\].records is '100'"),
    (lambda m: m.__setitem__("settings", "hg"), "field 'settings' is not an object"),
])
def test_malformed_manifests_name_the_field(tmp_path, edit, match):
    root = set_manifest(write_set(tmp_path / "d", 10, 0), edit)
    with pytest.raises(rdata.DataError, match=match):
        rdata.load_shards(root, "train")


def test_manifest_that_is_not_json_text_or_an_object(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    (root / "manifest.json").write_bytes(b"\x89PNG\x00\xff")
    with pytest.raises(rdata.DataError, match="not valid JSON"):
        rdata.read_manifest(root)
    (root / "manifest.json").write_text("[1, 2]")
    with pytest.raises(rdata.DataError, match="expected a JSON object, got list"):
        rdata.read_manifest(root)
    f = tmp_path / "a_file"
    f.write_text("x")
    with pytest.raises(rdata.DataError, match="not a folder"):
        rdata.read_manifest(f)


def test_empty_shard_and_absurd_or_all_zero_labels(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    (root / "train_00000_x.npy").write_bytes(b"")
    with pytest.raises(rdata.DataError, match="train_00000_x.npy: not a readable"):
        rdata.load_shards(root, "train")
    root = write_set(tmp_path / "e", 200, 0)
    y = np.load(root / "train_00001_y.npy")
    y[7] = 3e38  # finite, but no radiance per unit irradiance
    np.save(root / "train_00001_y.npy", y)
    with pytest.raises(rdata.DataError, match=r"train_00001_y.npy: row 7 .* in \[0, 1e\+06\]"):
        rdata.load_shards(root, "train")
    root = write_set(tmp_path / "f", 200, 0)
    for k in (0, 1):
        np.save(root / f"train_0000{k}_y.npy", np.zeros(100, np.float32))
    with pytest.raises(rdata.DataError, match="every training target is 0"):
        run(root, tmp_path / "r", "--epochs", "1")


def test_float16_gamma_from_non_finite_directions_is_refused(tmp_path):
    root = write_set(tmp_path / "d", 10, 0)
    x = np.load(root / "train_00000_x.npy")
    np.save(root / "train_00000_x.npy", x.astype(np.float16))
    meta = np.load(root / "train_00000_meta.npy")
    meta[:, 4:10] = 1.0
    meta[3, 5] = np.nan
    np.save(root / "train_00000_meta.npy", meta)
    with pytest.raises(rdata.DataError, match="train_00000_meta.npy: row 3's view or light"):
        rdata.load_shards(root, "train")


@pytest.mark.parametrize("flags,match", [
    (["--max-minutes", "nan"], "--max-minutes"),
    (["--max-minutes", "-1"], "--max-minutes"),
    (["--val-fraction", "7"], "--val-fraction"),
    (["--threads", "-3"], "--threads"),
    (["--seed", "-1"], "--seed"),
])
def test_numeric_flags_are_checked(record_set, tmp_path, capsys, flags, match):
    with pytest.raises(SystemExit):
        train.parse_args(["--data", str(record_set), "--run", str(tmp_path), *flags])
    assert match in capsys.readouterr().err


def test_levels_must_match_the_records(record_set, tmp_path, capsys):
    # Checked with the arguments, before any shard is read.
    with pytest.raises(SystemExit):
        train.parse_args(["--data", str(record_set), "--run", str(tmp_path), "--levels", "11"])
    assert "--levels 11: the network would read 2476 inputs" in capsys.readouterr().err


def test_the_same_set_twice_is_refused(record_set, tmp_path, capsys):
    with pytest.raises(SystemExit):
        train.parse_args(["--data", str(record_set), str(record_set), "--run", str(tmp_path)])
    assert "names a folder twice" in capsys.readouterr().err


def test_divergence_is_an_error_not_a_nan_model(record_set, tmp_path):
    with pytest.raises(SystemExit, match="training diverged at epoch 1"):
        run(record_set, tmp_path / "r", "--epochs", "2", "--lr", "1e30")


def test_resume_refuses_other_settings_and_damaged_checkpoints(record_set, tmp_path):
    run(record_set, tmp_path / "r", "--epochs", "1")
    # Another step size (once ignored without a word) or another set (once compared validation
    # losses of two sets) would mix two runs.
    with pytest.raises(SystemExit, match="lr: was 0.001, now 0.5"):
        run(record_set, tmp_path / "r", "--epochs", "2", "--resume", "--lr", "0.5")
    other = write_set(tmp_path / "other", 1200, 200, seed=1)
    with pytest.raises(SystemExit, match="data: was"):
        train.train(train.parse_args([
            "--data", str(other), "--run", str(tmp_path / "r"), "--width", "16", "--batch",
            "100", "--seed", "3", "--device", "cpu", "--quiet", "--epochs", "2", "--resume"]))
    # The same set in another folder (a moved checkout) is the same set.
    import shutil
    moved = shutil.copytree(record_set, tmp_path / "moved")
    train.train(train.parse_args([
        "--data", str(moved), "--run", str(tmp_path / "r"), "--width", "16", "--batch",
        "100", "--seed", "3", "--device", "cpu", "--quiet", "--epochs", "1", "--resume"]))
    # More epochs is a longer run of the same settings.
    res = run(record_set, tmp_path / "r", "--epochs", "2", "--resume")
    assert res["state"]["epoch"] == 2
    (tmp_path / "r" / "last.pt").write_bytes(b"garbage")
    with pytest.raises(SystemExit, match="last.pt: cannot resume from it"):
        run(record_set, tmp_path / "r", "--epochs", "3", "--resume")


def test_init_from_a_file_that_is_no_model(record_set, tmp_path):
    bad = tmp_path / "garbage.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(SystemExit, match="--init .*garbage.pt: cannot start from it"):
        run(record_set, tmp_path / "r", "--epochs", "1", "--init", str(bad))


def test_test_data_with_no_test_records(record_set, tmp_path):
    empty = set_manifest(write_set(tmp_path / "no_test", 200, 0, seed=2),
                         lambda m: m.__setitem__("clouds", [{"name": "c", "split": "train",
                                                             "seed": 2}]))
    with pytest.raises(rdata.DataError, match="no test records"):
        run(record_set, tmp_path / "r", "--epochs", "1", "--test-data", str(empty))


def test_evaluate_names_a_bad_model_and_refuses_meaningless_scores(record_set, tmp_path):
    for name, content in (("garbage.onnx", b"not a model"), ("folder.onnx", None),
                          ("missing.onnx", False)):
        path = tmp_path / name
        if content is None:
            path.mkdir()
        elif content:
            path.write_bytes(content)
        with pytest.raises(SystemExit, match=name):
            evaluate.main(["--data", str(record_set), "--model", str(path)])
    # A model trained for HG scored on Mie records, and a set with nothing to score.
    model = tmp_path / "m.onnx"
    run(record_set, tmp_path / "r", "--epochs", "1", "--export", str(model))
    mie = set_manifest(write_set(tmp_path / "mie", 200, 100, seed=4),
                       lambda m: m["settings"].__setitem__("phase", "mie"))
    with pytest.raises(SystemExit, match="trained for phase hg, the records .* have phase mie"):
        evaluate.main(["--data", str(mie), "--model", str(model)])
    # The same albedo written as 1 (not 1.0) is the same albedo.
    one = set_manifest(write_set(tmp_path / "one", 200, 100, seed=7),
                       lambda m: m["settings"].__setitem__("albedo", 1))
    assert evaluate.main(["--data", str(one), "--model", str(model)])["test"]["records"] == 100
    train_only = write_set(tmp_path / "train_only", 200, 0, seed=5)
    with pytest.raises(SystemExit, match="no validation or test records"):
        evaluate.main(["--data", str(train_only), "--model", str(model)])
    zero = write_set(tmp_path / "zero", 200, 100, seed=6)
    np.save(zero / "test_00000_y.npy", np.zeros(100, np.float32))
    with pytest.raises(SystemExit, match="no positive target"):
        evaluate.main(["--data", str(zero), "--model", str(model)])
    # --card with the card's own set: its test split is on the card already.
    with pytest.raises(SystemExit, match="one of the card's own data sets"):
        evaluate.main(["--data", str(record_set), "--model", str(model), "--card"])


def test_run_and_export_paths_are_checked_before_training(record_set, tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    base = ["--data", str(record_set), "--epochs", "1", "--width", "16", "--device", "cpu",
            "--quiet"]
    with pytest.raises(SystemExit, match="--run .*a_file: not a folder"):
        train.main([*base, "--run", str(f)])
    with pytest.raises(SystemExit, match="--export .*: a folder"):
        train.main([*base, "--run", str(tmp_path / "r"), "--export", str(tmp_path)])
    with pytest.raises(SystemExit, match="--export .*cannot be written"):
        train.main([*base, "--run", str(tmp_path / "r"), "--export", str(f / "m.onnx")])
    assert not (tmp_path / "r" / "last.pt").exists()  # refused before the first epoch
