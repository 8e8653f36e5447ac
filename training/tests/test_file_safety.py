"""Files that are not what a reader expects (a named pipe, a link to /dev/zero, a symbolic link
loop or a link to nothing, a file over the memory budget, a shard changed after datagen wrote
it): every script refuses them at once with one line ``error: <path>: <what>`` and exit status
2, never a hang, a traceback or a model trained on damaged records.

Every case that could block is bounded: the scripts run as subprocesses with a timeout, and
in-process reads of a pipe run under ``signal.alarm``."""

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import train
from conftest import write_set
from rpnn import data as rdata
from rpnn import safe_io

ROOT = Path(__file__).resolve().parents[2]
TRAINING = ROOT / "training"
TIMEOUT = 30  # seconds: a refusal takes ~3 s (importing torch); a hang is a failure


@contextlib.contextmanager
def alarm(seconds=TIMEOUT):
    """Fails the test instead of hanging when a read blocks."""
    def fire(*_):
        raise TimeoutError(f"still blocked after {seconds} s")
    old = signal.signal(signal.SIGALRM, fire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def script(name, *args, env=None):
    """Runs a training script; returns (exit status, stderr). A hang fails after TIMEOUT."""
    e = {k: v for k, v in os.environ.items() if k != safe_io.ENV}
    e.update(env or {})
    r = subprocess.run([sys.executable, str(TRAINING / name), *map(str, args)], cwd=ROOT,
                       env=e, capture_output=True, text=True, timeout=TIMEOUT)
    return r.returncode, r.stderr


def assert_refused(rc, err, path, *words):
    """Exit status 2 and one line `error: <path>: ...` with `words`, no traceback."""
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and str(path) in lines[0], err
    for w in words:
        assert w in lines[0], err


def make_bad(path: Path, kind: str) -> tuple:
    """Replaces `path` by a bad thing of `kind`; returns words the refusal must contain."""
    if path.exists() or path.is_symlink():
        path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
        return ("named pipe",)
    if kind == "dev-zero":
        path.symlink_to("/dev/zero")
        return ("character device",)
    if kind == "loop":
        path.symlink_to(path.name)
        return ("loops",)
    if kind == "dangling":
        path.symlink_to(path.with_name("nothing-here"))
        return ("dangling",)
    raise AssertionError(kind)


KINDS = ["fifo", "dev-zero", "loop", "dangling"]


@pytest.fixture
def small_set(tmp_path):
    return write_set(tmp_path / "data", 200, 100, sha256=True)


def train_args(data, run, *extra):
    return [str(a) for a in ("--data", data, "--run", run, "--epochs", "1", "--width", "16",
                             "--batch", "100", "--device", "cpu", "--quiet", *extra)]


# --- the four inputs, each as a pipe, a link to /dev/zero, a link loop and a dangling link ---

@pytest.mark.parametrize("kind", KINDS)
def test_manifest(small_set, tmp_path, kind):
    path = small_set / "manifest.json"
    words = make_bad(path, kind)
    assert_refused(*script("train.py", *train_args(small_set, tmp_path / "r")), path, *words)


@pytest.mark.parametrize("kind", KINDS)
def test_shard(small_set, tmp_path, kind):
    path = small_set / "train_00001_x.npy"
    words = make_bad(path, kind)
    assert_refused(*script("train.py", *train_args(small_set, tmp_path / "r")), path, *words)


@pytest.mark.parametrize("kind", KINDS)
def test_init(small_set, tmp_path, kind):
    path = tmp_path / "start.pt"
    words = make_bad(path, kind)
    rc, err = script("train.py", *train_args(small_set, tmp_path / "r", "--init", path))
    assert_refused(rc, err, path, "--init", *words)
    assert not (tmp_path / "r" / "last.pt").exists()


@pytest.mark.parametrize("kind", KINDS)
def test_model(small_set, tmp_path, kind):
    path = tmp_path / "m.onnx"
    words = make_bad(path, kind)
    rc, err = script("evaluate.py", "--data", small_set, "--model", path)
    assert_refused(rc, err, path, *words)
    assert "no such file" not in err  # a pipe is not "no such file"


# --- damaged shards: the manifest's SHA-256 ---

def flip_one_byte(path: Path) -> None:
    """Flips the lowest bit of the first value's first byte (little-endian float32: a mantissa
    bit), so the value stays finite and in range, which no check of the values can see."""
    with open(path, "rb") as f:
        np.lib.format.read_magic(f)
        np.lib.format.read_array_header_1_0(f)
        offset = f.tell()
    b = bytearray(path.read_bytes())
    b[offset] ^= 1
    path.write_bytes(bytes(b))
    assert np.isfinite(np.load(path)).all()


@pytest.mark.parametrize("which,name", [(0, "train_00001_x.npy"), (1, "train_00000_y.npy"),
                                        (2, "test_00000_meta.npy")])
def test_a_flipped_byte_is_refused_naming_the_shard(small_set, which, name):
    rdata.load_shards(small_set, "train")  # intact: loads
    flip_one_byte(small_set / name)
    split = name.split("_")[0]
    with pytest.raises(rdata.DataError, match=rf"{name}: SHA-256 .* shards\[\d+\]\.sha256"
                                              rf"\[{which}\]"):
        rdata.load_shards(small_set, split)


def test_train_refuses_a_flipped_byte(small_set, tmp_path):
    path = small_set / "train_00000_x.npy"
    flip_one_byte(path)
    rc, err = script("train.py", *train_args(small_set, tmp_path / "r"))
    assert_refused(rc, err, path, "SHA-256", "shards[0].sha256[0]")
    assert not (tmp_path / "r" / "last.pt").exists()


def test_an_intact_set_with_sums_trains(small_set, tmp_path):
    res = train.train(train.parse_args(train_args(small_set, tmp_path / "r")))
    assert res["state"]["epoch"] == 1
    assert (res["fit"] + res["val"], res["test"]) == (200, 100)


def test_a_malformed_sum_names_the_field(small_set):
    m = json.loads((small_set / "manifest.json").read_text())
    m["shards"][1]["sha256"] = ["00" * 32, "xyz"]
    (small_set / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(rdata.DataError, match=r"manifest.json: shards\[1\].sha256 is"):
        rdata.read_manifest(small_set)


# --- the memory budget ---

def test_a_shard_over_the_budget_is_refused_naming_it(tmp_path):
    root = write_set(tmp_path / "data", 10, 0)  # a 0.5 KiB manifest, a 88 KiB shard
    shard = root / "train_00000_x.npy"
    rc, err = script("train.py", *train_args(root, tmp_path / "r"),
                     env={safe_io.ENV: "1K"})
    assert_refused(rc, err, shard, "memory budget of 1.0 KiB")
    rc, err = script("train.py", *train_args(root, tmp_path / "r", "--max-memory", "2K"))
    assert_refused(rc, err, shard, "memory budget of 2.0 KiB")
    # The same set within the budget trains.
    train.train(train.parse_args(train_args(root, tmp_path / "r", "--max-memory", "1M")))


def test_a_budget_that_is_no_size_is_named(small_set, tmp_path):
    rc, err = script("train.py", *train_args(small_set, tmp_path / "r"),
                     env={safe_io.ENV: "lots"})
    assert_refused(rc, err, "NIMBUS_MAX_MEMORY=lots", "expected a size")
    with pytest.raises(SystemExit):
        train.parse_args(train_args(small_set, tmp_path / "r", "--max-memory", "0"))


def test_sizes_parse_as_the_renderer_parses_them():
    assert safe_io.parse_size("6G") == 6 << 30
    assert safe_io.parse_size("512m") == 512 << 20
    assert safe_io.parse_size("1.5GiB") == 3 << 29
    assert safe_io.parse_size("1000") == 1000
    for bad in ("", "G", "-1G", "6X", "0", "1e999", "99999999999999999999T"):
        with pytest.raises(ValueError):
            safe_io.parse_size(bad)
    assert 256 << 20 < safe_io.default_budget() < 1 << 50


# --- the other readers and kinds ---

def test_a_folder_and_a_socket_are_said_as_such(tmp_path):
    (tmp_path / "dir.json").mkdir()
    with pytest.raises(safe_io.InputError, match="dir.json: a folder"):
        safe_io.load_json(tmp_path / "dir.json")
    s = socket.socket(socket.AF_UNIX)
    try:
        s.bind(str(tmp_path / "sock"))
        with alarm(), pytest.raises(safe_io.InputError, match="sock: a socket"):
            safe_io.read_bytes(tmp_path / "sock")
    finally:
        s.close()


def test_resume_from_a_pipe_is_refused(small_set, tmp_path):
    run = tmp_path / "r"
    train.train(train.parse_args(train_args(small_set, run)))
    (run / "last.pt").unlink()
    os.mkfifo(run / "last.pt")
    with alarm(), pytest.raises(safe_io.InputError, match="last.pt: a named pipe"):
        train.train(train.parse_args(train_args(small_set, run, "--epochs", "2", "--resume")))


def test_quantize_and_train_sky_refuse_a_pipe(small_set, tmp_path):
    path = tmp_path / "m.onnx"
    os.mkfifo(path)
    assert_refused(*script("quantize.py", path), path, "named pipe")
    assert_refused(*script("train_sky.py", "--init", path, "--data", small_set, "--run",
                           tmp_path / "r"), path, "named pipe")


def test_a_model_card_that_is_a_pipe_is_refused(small_set, tmp_path):
    """evaluate.py --card reads the card next to the model: a pipe there is said as such."""
    model = tmp_path / "m.onnx"
    model.write_bytes(b"whatever")
    os.mkfifo(tmp_path / "m.json")
    rc, err = script("evaluate.py", "--data", small_set, "--model", model, "--card")
    assert_refused(rc, err, tmp_path / "m.json", "named pipe")


def test_outputs_replace_a_pipe_left_at_their_path(small_set, tmp_path):
    """The run's log and plot are written beside and renamed over their path: a pipe there is
    replaced, never opened (opening it for writing would wait for a reader)."""
    run = tmp_path / "r"
    run.mkdir()
    for name in ("log.csv", "curves.png"):
        os.mkfifo(run / name)
    with alarm():
        train.train(train.parse_args(train_args(small_set, run)))
    assert (run / "log.csv").is_file() and (run / "curves.png").is_file()
    assert (run / "log.csv").read_text().startswith("epoch,")
