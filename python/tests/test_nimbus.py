"""The Python module against the CLI, the .vol reader, the Mitsuba references, bad input, the
GIL, Ctrl-C and the progressive estimator. Seeds are fixed; every test asserts numbers.

Run: training/.venv/bin/python -m pytest python/tests (after `pip install ./python`).
"""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import nimbus

ROOT = Path(__file__).resolve().parents[2]
REFS = ROOT.parent / "shared" / "refs"
CUBE_SCENE = ROOT / "scenes" / "refs" / "cube_iso.toml"
CLI = Path(os.environ.get("NIMBUS_BIN", ROOT / "target" / "release" / "nimbus"))


def cube_array():
    return nimbus.Volume.load(REFS / "volumes" / "cube.vol").to_numpy()


def cube_scene(volume, width=128, height=96):
    """scenes/refs/cube_iso.toml, field for field."""
    return nimbus.Scene(
        volume=volume, aabb_min=(-0.5, -0.5, -0.5), aabb_max=(0.5, 0.5, 0.5),
        density_scale=4.0, albedo=0.8, phase=nimbus.Isotropic(),
        sun=nimbus.Sun(direction=(0.5, 0.7, 1.0), irradiance=(1.0, 1.0, 1.0)),
        camera=nimbus.Camera(origin=(1.6, 1.2, 2.4), target=(0, 0, 0), up=(0, 1, 0),
                             vfov_deg=34.0, width=width, height=height))


def small_scene(width=32, height=24):
    vol = nimbus.generate("cumulus", seed=3, res=(24, 18, 24))
    return nimbus.Scene(volume=vol, density_scale=20.0, phase=nimbus.HenyeyGreenstein(0.857),
                        sun=nimbus.Sun(direction=(1, 0.6, 0.3)),
                        camera=nimbus.Camera(origin=(0.3, 0.3, 3.0), target=(0, 0, 0),
                                             vfov_deg=40, width=width, height=height))


@pytest.mark.skipif(not CLI.is_file(), reason=f"{CLI} not built (cargo build --release -p nimbus-cli)")
@pytest.mark.parametrize("method,budget", [("pt", {"spp": 4}), ("rpnn", {"spp": 2})])
def test_same_pixels_as_the_cli(tmp_path, method, budget):
    """The scene file rendered by `nimbus render` and, with the same seed, by Python from the
    file and from a numpy copy of its volume: identical pixels (the same estimator call)."""
    exr = tmp_path / "cli.exr"
    flags = ["--backend", "ort"] if method == "rpnn" else []
    subprocess.run([str(CLI), "render", str(CUBE_SCENE), "--method", method, "--spp",
                    str(budget["spp"]), "--seed", "5", "-q", "-o", str(exr), *flags],
                   check=True, capture_output=True, cwd=ROOT)
    cli = nimbus.Image.load(exr).rgb
    settings = {"backend": "ort"} if method == "rpnn" else {}
    from_file = nimbus.render(nimbus.Scene.load(CUBE_SCENE), method, seed=5, **budget, **settings)
    from_numpy = nimbus.render(cube_scene(nimbus.Volume.from_numpy(cube_array())), method,
                               seed=5, **budget, **settings)
    assert cli.shape == (96, 128, 3) and cli.mean() > 0.01
    assert np.array_equal(from_file.rgb, cli)
    assert np.array_equal(from_numpy.rgb, cli)


def test_numpy_density_equals_the_vol_file(tmp_path):
    """A numpy density (any dtype, any layout) equals the same density read from .vol."""
    vol = nimbus.Volume.load(REFS / "volumes" / "cube.vol")
    a = vol.to_numpy()
    assert a.shape == vol.shape == (16, 16, 16) and a.dtype == np.float32
    for arr in [a, a.astype(np.float64), np.asfortranarray(a),
                a.transpose(2, 1, 0).copy().transpose(2, 1, 0)]:
        assert np.array_equal(nimbus.Volume.from_numpy(arr).to_numpy(), a)
    # Written back as .vol and read again: the same voxels and box.
    v = nimbus.Volume.from_numpy(a, aabb_min=(-0.5, -0.5, -0.5), aabb_max=(0.5, 0.5, 0.5))
    v.save(tmp_path / "cube.vol")
    back = nimbus.Volume.load(tmp_path / "cube.vol")
    assert np.array_equal(back.to_numpy(), a)
    assert back.aabb == ((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    # Integers convert exactly.
    i = (np.arange(4 * 5 * 6) % 7).reshape(4, 5, 6).astype(np.uint16)
    assert np.array_equal(nimbus.Volume.from_numpy(i).to_numpy(), i.astype(np.float32))


def test_agrees_with_the_mitsuba_reference():
    """cube_iso at 256 spp against ../shared/refs (tests/tests/refs.rs's tolerances: at 256 spp
    the mean over 4 159 cloud pixels has σ ≈ 0.09 %, so 5σ ≈ 0.45 % → 0.5 %; a 4×4 block
    ≈ 1.5 % from noise, 2.2 % leaves room for the reference's own noise)."""
    if not (REFS / "cube_iso.exr").is_file():
        pytest.skip("../shared/refs is not beside the checkout")
    img = nimbus.render(cube_scene(nimbus.Volume.from_numpy(cube_array())), "pt", spp=256,
                        seed=2024)
    m = nimbus.compare(img, REFS / "cube_iso.exr", mask=REFS / "cube_iso_tau.npy")
    assert m["nonfinite"] == 0
    assert abs(m["mean_lum_ratio"] - 1.0) < 0.005, m
    assert m["rel_rmse_cloud_4x4"] < 0.022, m
    # The EXR's own mask is found beside it, as `nimbus compare` finds it.
    assert nimbus.compare(img, REFS / "cube_iso.exr") == m


def _bad(a):
    return lambda: nimbus.Volume.from_numpy(a)


def _nan():
    a = np.ones((4, 5, 6))
    a[1, 2, 3] = np.nan
    return a


def _neg():
    a = np.ones((4, 5, 6), dtype=np.float32)
    a[3, 0, 1] = -0.5
    return a


def _inf():
    a = np.ones((4, 5, 6))
    a[0, 4, 5] = np.inf
    return a


def _scene(**kw):
    args = dict(volume=nimbus.Volume.from_numpy(np.ones((4, 4, 4))),
                camera=nimbus.Camera(origin=(0, 0, 3), target=(0, 0, 0)),
                aabb_min=(-1, -1, -1), aabb_max=(1, 1, 1))
    args.update(kw)
    return nimbus.Scene(**args)


BAD_INPUT = [
    ("nan voxel", _bad(_nan()), ValueError, "density[1, 2, 3]"),
    ("negative voxel", _bad(_neg()), ValueError, "density[3, 0, 1]"),
    ("infinite voxel", _bad(_inf()), ValueError, "density[0, 4, 5]"),
    ("rank 2", _bad(np.ones((4, 4))), ValueError, "3-D array"),
    ("rank 4", _bad(np.ones((2, 2, 2, 2))), ValueError, "3-D array"),
    ("empty axis", _bad(np.ones((0, 4, 4))), ValueError, "empty along axis 0"),
    ("complex dtype", _bad(np.ones((2, 2, 2), dtype=complex)), TypeError, "dtype"),
    ("box inverted", lambda: nimbus.Volume.from_numpy(np.ones((2, 2, 2)), (1, 1, 1), (0, 0, 0)),
     ValueError, "aabb_max"),
    ("one corner", lambda: nimbus.Volume.from_numpy(np.ones((2, 2, 2)), (0, 0, 0)), ValueError,
     "aabb_max"),
    ("hg g", lambda: nimbus.HenyeyGreenstein(1.5), ValueError, "g"),
    ("camera width", lambda: nimbus.Camera((0, 0, 3), (0, 0, 0), width=0), ValueError,
     "camera.width"),
    ("camera fov", lambda: nimbus.Camera((0, 0, 3), (0, 0, 0), vfov_deg=190), ValueError,
     "vfov"),
    ("sun direction", lambda: nimbus.Sun(direction=(0, 0, 0)), ValueError, "direction"),
    ("sky both", lambda: nimbus.Sky(radiance=1.0, envmap=np.ones((4, 8, 3))), ValueError, "sky"),
    ("envmap shape", lambda: nimbus.Sky(envmap=np.ones((4, 8))), ValueError, "envmap"),
    ("density scale", lambda: _scene(density_scale=-1.0), ValueError, "density_scale"),
    ("albedo", lambda: _scene(albedo=1.5), ValueError, "albedo"),
    ("no box", lambda: _scene(aabb_min=None, aabb_max=None), ValueError, "aabb_min"),
    ("spp", lambda: _scene(spp=0), ValueError, "render.spp"),
    ("method", lambda: nimbus.render(_scene(), "mc"), ValueError, "method"),
    ("unknown setting", lambda: nimbus.render(_scene(), "pt", sky_dir=4), ValueError,
     "unknown setting `sky_dir`"),
    ("setting value", lambda: nimbus.render(_scene(), "rpnn", sky_dirs=0), ValueError,
     "sky_dirs"),
    ("setting choice", lambda: nimbus.render(_scene(), "pm", pm_variant="elek"), ValueError,
     "exact, elek2012"),
    ("render spp", lambda: nimbus.render(_scene(), "pt", spp=0), ValueError, "spp"),
    ("frames on pt", lambda: nimbus.render(_scene(), "pt", frames=4), ValueError, "frames"),
    ("max_memory", lambda: nimbus.max_memory("lots"), ValueError, "max_memory"),
    ("threads", lambda: nimbus.set_threads(0), ValueError, "1..=1024"),
    ("missing file", lambda: nimbus.Volume.load("/nonexistent/cloud.vol"), OSError,
     "/nonexistent/cloud.vol"),
    ("compare sizes", lambda: nimbus.compare(np.ones((4, 4, 3)), np.ones((8, 4, 3))),
     ValueError, "4x4"),
]


@pytest.mark.parametrize("name,call,exc,needle", BAD_INPUT, ids=[b[0] for b in BAD_INPUT])
def test_bad_input(name, call, exc, needle):
    """Each bad input raises its exception with a message naming the index or the field."""
    with pytest.raises(exc) as e:
        call()
    assert needle in str(e.value), str(e.value)


def test_memory_budget_refuses_a_large_array():
    """An array over max_memory= is refused with the budget named, not allocated."""
    old = nimbus.max_memory()
    try:
        nimbus.max_memory(1024)
        with pytest.raises(ValueError, match="memory budget"):
            nimbus.Volume.from_numpy(np.ones((16, 16, 16), dtype=np.float32))
    finally:
        nimbus.max_memory(old)


def test_the_gil_is_released_during_a_render():
    """Another Python thread keeps running while Rust renders."""
    scene = cube_scene(nimbus.Volume.from_numpy(cube_array()))
    ticks = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.002)

    t = threading.Thread(target=count)
    t.start()
    t0 = time.perf_counter()
    img = nimbus.render(scene, "pt", spp=64, seed=1)
    t1 = time.perf_counter()
    stop.set()
    t.join()
    during = [x for x in ticks if t0 < x < t1]
    assert t1 - t0 > 0.2, "render too short to measure"
    # At one tick per ~2 ms the thread ticks hundreds of times; holding the GIL it would not
    # tick at all (a tick per 100 ms poll at most).
    assert len(during) > 0.25 * (t1 - t0) / 0.002, (len(during), t1 - t0)
    assert img.rgb.mean() > 0.01


CTRL_C_CHILD = r"""
import sys, time
import nimbus
scene = nimbus.Scene.load(sys.argv[1])
print("ready", flush=True)
try:
    nimbus.render(scene, "pt", spp=1 << 20, seed=1)
    print("finished", flush=True)
except KeyboardInterrupt:
    print("interrupted", time.time(), flush=True)
img = nimbus.render(scene, "pt", spp=1, seed=1)
print("usable", img.rgb.shape, flush=True)
"""


def test_ctrl_c_stops_a_long_render():
    """SIGINT mid-render raises KeyboardInterrupt within 2 s and leaves the interpreter usable."""
    p = subprocess.Popen([sys.executable, "-c", CTRL_C_CHILD, str(CUBE_SCENE)],
                         stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(1.0)  # well into the render (≈ 10⁶ spp would take hours)
    sent = time.time()
    os.kill(p.pid, signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    lines = out.splitlines()
    assert lines[0].startswith("interrupted"), out
    assert float(lines[0].split()[1]) - sent < 2.0, out
    assert lines[1] == "usable (96, 128, 3)", out
    assert p.returncode == 0


def test_estimator_change_restarts_accumulation():
    """accumulate adds samples; change(sun=/camera=/density=) and restart start at zero; the
    progressive image at n samples is the mean of its samples."""
    scene = small_scene()
    e = nimbus.Estimator(scene, "pt", seed=3)
    assert e.samples == 0
    assert e.accumulate(2) == 2 and e.accumulate(3) == 5 and e.samples == 5
    before = e.image().rgb
    assert before.mean() > 0.0
    e.change(sun=(-1.0, 0.6, 0.3))
    assert e.samples == 0
    e.accumulate(5)
    after = e.image().rgb
    assert not np.array_equal(before, after)
    e.change(camera=nimbus.Camera(origin=(0, 0, 3), target=(0, 0, 0), width=16, height=12))
    assert e.samples == 0
    e.accumulate(1)
    assert e.image().rgb.shape == (12, 16, 3)
    d = scene.volume.to_numpy()
    e.change(density=d * 0.0)
    assert e.samples == 0
    e.accumulate(2)
    assert e.image().rgb.max() == 0.0  # no cloud, no sky: black
    with pytest.raises(ValueError, match="resolution"):
        e.change(density=np.ones((2, 2, 2)))
    e.restart()
    assert e.samples == 0


def test_render_equals_estimator_render_and_scene_round_trip(tmp_path):
    """A scene saved (its numpy volume beside it as .npy) and loaded renders the same pixels."""
    generated = small_scene()
    vol = nimbus.Volume.from_numpy(generated.volume.to_numpy(), *generated.volume.aabb)
    scene = nimbus.Scene(volume=vol, density_scale=20.0, phase=nimbus.HenyeyGreenstein(0.857),
                         sun=nimbus.Sun(direction=(1, 0.6, 0.3)),
                         camera=nimbus.Camera(origin=(0.3, 0.3, 3.0), target=(0, 0, 0),
                                              vfov_deg=40, width=32, height=24))
    a = nimbus.render(scene, "pt", spp=4, seed=9)
    assert np.array_equal(a.rgb, nimbus.render(generated, "pt", spp=4, seed=9).rgb)
    scene.save(tmp_path / "s.toml")
    assert (tmp_path / "s.npy").is_file()
    generated.save(tmp_path / "g.toml")  # a generator, written as one
    assert "generator" in (tmp_path / "g.toml").read_text()
    for saved in ["s.toml", "g.toml"]:
        loaded = nimbus.Scene.load(tmp_path / saved)
        b = nimbus.render(loaded, "pt", spp=4, seed=9)
        assert np.array_equal(a.rgb, b.rgb), saved
    c = nimbus.Estimator(scene, "pt").render(4, seed=9)
    assert np.array_equal(a.rgb, c.rgb)
    a.save(tmp_path / "a.exr")
    a.save(tmp_path / "a.png")
    assert np.array_equal(nimbus.Image.load(tmp_path / "a.exr").rgb, a.rgb)
    assert a._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"
    assert a.variance.shape == (24, 32)


def test_tau_and_compare():
    """tau is the camera optical depth (the cloud mask τ ≥ 0.1); an image against itself has
    zero error and ratio 1."""
    scene = small_scene()
    t = nimbus.tau(scene)
    assert t.shape == (24, 32) and t.min() >= 0.0 and (t >= 0.1).sum() > 16
    img = nimbus.render(scene, "pt", spp=2, seed=1)
    m = nimbus.compare(img, img.rgb, mask=t >= 0.1)
    assert m["rel_rmse_cloud"] == 0.0 and m["mean_lum_ratio"] == 1.0
    assert m["cloud_pixels"] == (t >= 0.1).sum()


def test_env_map_sky_from_numpy():
    """A constant environment map from numpy lights the cloud as the same constant sky."""
    vol = nimbus.generate("cumulus", seed=3, res=(24, 18, 24))
    cam = nimbus.Camera(origin=(0.3, 0.3, 3.0), target=(0, 0, 0), width=16, height=12)
    const = nimbus.Scene(volume=vol, density_scale=20.0, sky=nimbus.Sky(radiance=0.5), camera=cam)
    env = nimbus.Scene(volume=vol, density_scale=20.0,
                       sky=nimbus.Sky(envmap=np.full((8, 16, 3), 0.5)), camera=cam)
    a = nimbus.render(const, "pt", spp=64, seed=2).rgb.mean()
    b = nimbus.render(env, "pt", spp=64, seed=2).rgb.mean()
    # Same integral, other sampling: 64 spp over 192 pixels leaves well under 2 % of noise.
    assert abs(a / b - 1.0) < 0.02, (a, b)


def test_quickstart_example_runs(tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "python" / "quickstart.py"),
                          str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "pt.png").is_file() and (tmp_path / "rpnn.png").is_file()
    err = float(out.stdout.split("4x4 error ")[1].split(",")[0])
    # The shipped network on a ball it was not trained on, 4 spp against 64 spp of pt.
    assert err < 0.3, out.stdout


@pytest.mark.skipif(not CLI.is_file(), reason=f"{CLI} not built (cargo build --release -p nimbus-cli)")
@pytest.mark.parametrize("method,budget,flags", [
    ("pt-gpu", {"spp": 4}, ["--spp", "4"]),
    ("pm", {"spp": 2}, ["--spp", "2"]),
    ("pm-march", {"frames": 4}, ["--ring", "4"]),
])
def test_gpu_methods_same_pixels_as_the_cli(tmp_path, method, budget, flags):
    """pt-gpu, pm and pm-march (on lavapipe without a GPU) from Python and from `nimbus render`
    of the same scene file, seed 5: identical pixels."""
    scene = small_scene()
    scene.save(tmp_path / "s.toml")
    exr = tmp_path / "cli.exr"
    subprocess.run([str(CLI), "render", str(tmp_path / "s.toml"), "--method", method, *flags,
                    "--seed", "5", "-q", "-o", str(exr)], check=True, capture_output=True, cwd=ROOT)
    cli = nimbus.Image.load(exr).rgb
    py = nimbus.render(nimbus.Scene.load(tmp_path / "s.toml"), method, seed=5, **budget).rgb
    assert py.shape == (24, 32, 3) and py.mean() > 0.0
    assert np.array_equal(py, cli), (method, np.abs(py - cli).max())


def test_compare_scene_table_and_pt_error_falls_with_budget(tmp_path):
    """compare_scene runs `nimbus compare SCENE`: one row per budget with the report's columns;
    the path tracer's 4x4-block error against the cached reference falls with spp (1 → 16 spp
    divides Monte Carlo noise by ≈ 4; asserted: by more than 2)."""
    rows = nimbus.compare_scene(small_scene(), "pt", out=tmp_path / "report",
                                budgets={"pt": [1, 16]}, ref_spp=256, ref_noise=0.0,
                                ref_time_cap=60.0, cache=None, seed=4)
    assert [r["budget"] for r in rows] == [1, 16], rows
    for key in ["method", "budget", "budget_unit", "time_s", "device", "rel_rmse",
                "rel_rmse_4x4", "mean_ratio", "bias", "bias_floor", "nonfinite"]:
        assert key in rows[0], rows[0].keys()
    assert rows[0]["method"] == "pt" and rows[1]["nonfinite"] == 0
    e1, e16 = rows[0]["rel_rmse_4x4"], rows[1]["rel_rmse_4x4"]
    assert 0.0 < e16 < e1 / 2, (e1, e16)
    assert (tmp_path / "report" / "report.csv").is_file()


class _FakeTqdm:
    """tqdm's interface as render(progress=True) uses it: tqdm(total), update(n), close()."""
    made = []

    def __init__(self, total):
        self.total, self.n, self.closed = total, 0, False
        _FakeTqdm.made.append(self)

    def update(self, n):
        self.n += n

    def close(self):
        self.closed = True


def test_render_progress_steps_a_tqdm_bar(monkeypatch):
    """With tqdm importable, render(progress=True) steps a bar once per sample to the budget and
    (for pt) gives render's pixels; tqdm is not a pinned requirement, so a stand-in module."""
    import types
    fake = types.ModuleType("tqdm")
    fake.tqdm = _FakeTqdm
    monkeypatch.setitem(sys.modules, "tqdm", fake)
    scene = small_scene()
    img = nimbus.render(scene, "pt", spp=6, seed=2, progress=True)
    bar = _FakeTqdm.made[-1]
    assert (bar.total, bar.n, bar.closed) == (6, 6, True)
    assert np.array_equal(img.rgb, nimbus.render(scene, "pt", spp=6, seed=2).rgb)


DATAGEN = dict(clouds="gen:5", test_records=6, val_records=4, samples=64, eval_samples=64,
               shard_size=10, seed=3, device="cpu")
DATAGEN_FLAGS = ["--clouds", "gen:5", "--test-records", "6", "--val-records", "4", "--samples",
                 "64", "--eval-samples", "64", "--shard-size", "10", "--seed", "3",
                 "--device", "cpu", "-q"]


@pytest.mark.skipif(not CLI.is_file(), reason=f"{CLI} not built (cargo build --release -p nimbus-cli)")
def test_datagen_equals_the_cli_shards(tmp_path):
    """The same settings and seed: the arrays datagen returns are the rows of the CLI's shards
    (every split, every column, bit for bit), and datagen(out=) writes the same files."""
    cli = tmp_path / "cli"
    t = time.perf_counter()
    subprocess.run([str(CLI), "datagen", "--records", "24", "-o", str(cli), *DATAGEN_FLAGS],
                   check=True, capture_output=True)
    cli_s = time.perf_counter() - t
    d = nimbus.datagen(24, **DATAGEN)
    for split, n in [("train", 24), ("val", 4), ("test", 6)]:
        for k, shape in [("x", (n, 2251)), ("y", (n,)), ("meta", (n, 15))]:
            ref = np.concatenate([np.load(f) for f in sorted(cli.glob(f"{split}_*_{k}.npy"))])
            assert d[split][k].shape == shape and d[split][k].dtype == np.float32
            assert np.array_equal(d[split][k], ref), (split, k)
    assert d["records"] == 34 and len(d["meta_names"]) == 15
    assert np.all(d["train"]["meta"][:, 10] == 64)  # samples column: exactly 64 each
    s = nimbus.datagen(24, out=tmp_path / "py", **DATAGEN)
    assert s["records"] == s["computed"] == 34
    for f in sorted(cli.iterdir()):
        if f.suffix in (".npy", ".sha256"):
            assert (tmp_path / "py" / f.name).read_bytes() == f.read_bytes(), f.name
    print(f"datagen 34 records: CLI process {34 / cli_s:.1f} records/s, "
          f"Python in memory {d['records_per_second']:.1f}, Python to shards "
          f"{s['records_per_second']:.1f}")


def test_datagen_bad_settings():
    with pytest.raises(ValueError, match="light"):
        nimbus.datagen(4, light="cone")
    with pytest.raises(ValueError, match="density_range"):
        nimbus.datagen(4, density_range=(80.0, 10.0))
    with pytest.raises(ValueError, match="shard"):
        nimbus.datagen(4, shard="1/2")


DATAGEN_CTRL_C_CHILD = r"""
import time
import nimbus
print("ready", flush=True)
try:
    # 10^5 records of 65 536 samples each: hours on two cores.
    nimbus.datagen(100000, clouds="gen:2", test_records=0, val_records=0, samples=65536,
                   device="cpu", seed=1)
    print("finished", flush=True)
except KeyboardInterrupt:
    print("interrupted", time.time(), flush=True)
d = nimbus.datagen(2, clouds="gen:5", test_records=0, val_records=0, samples=16, device="cpu")
print("usable", d["train"]["x"].shape, flush=True)
"""


def test_ctrl_c_stops_datagen():
    """SIGINT during datagen raises KeyboardInterrupt within 2 s (a cancel check between
    records) and the interpreter makes records again."""
    p = subprocess.Popen([sys.executable, "-c", DATAGEN_CTRL_C_CHILD], stdout=subprocess.PIPE,
                         text=True, cwd=ROOT)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(2.0)  # clouds built, records under way
    sent = time.time()
    os.kill(p.pid, signal.SIGINT)
    out, _ = p.communicate(timeout=120)
    lines = out.splitlines()
    assert lines[0].startswith("interrupted"), out
    assert float(lines[0].split()[1]) - sent < 2.0, out
    assert lines[1] == "usable (2, 2251)", out


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_from_numpy_copies_the_array_at_most_once(dtype):
    """Peak memory of Volume.from_numpy: the renderer's float32 copy and nothing more (a
    transposed, non-contiguous view of float64 included: no intermediate contiguous or
    converted copy). Measured in a fresh process with ru_maxrss, the process's peak; the
    allowance of 16 MiB over the copy covers the allocator and the module's own pages."""
    code = f"""
import resource, numpy as np, nimbus
a = np.ones((160, 256, 256), dtype=np.{dtype}).transpose(2, 1, 0)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
v = nimbus.Volume.from_numpy(a)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(peak - base, a.size * 4)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    grown, copy = map(int, r.stdout.split())
    assert grown <= copy + (16 << 20), (grown, copy)
