#!/usr/bin/env python3
"""Nimbus against Mitsuba 3 from Python, side by side: the same numpy density handed to
`nimbus.Volume.from_numpy` and to `mi.VolumeGrid`, the same scene (shared/refs/cases/
cumulus_side.json: heterogeneous medium, HG g = 0.857, delta sun as a directional emitter, no
sky), the same metric (`nimbus.compare`: relative RMSE over 4x4 blocks of cloud pixels, the
definition of shared/refs/compare.py) against the high-spp Mitsuba reference of shared/refs.

  training/.venv/bin/python bench/python_vs_mitsuba.py --mitsuba-python /tmp/mi/bin/python \
      --spp 256 1024 --rpnn-spp 4 16

Mitsuba runs in its own venv (`python3 -m venv /tmp/mi && /tmp/mi/bin/pip install mitsuba`),
as a child process of this script (`--worker`) that renders and hands back the images as .npy;
its time excludes kernel compilation (a 4-spp warm-up render runs first), Nimbus' excludes
nothing but the import. Time to 5 %: a budget under 5 % gives an upper bound (its time); above, error ∝ spp^-1/2
(time ∝ spp) for the unbiased path tracers; the largest budget's row is the estimate.
Prints a Markdown table and one JSON line per row.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REFS = ROOT.parent / "shared" / "refs"
TARGET = 0.05


def load_case(case_path):
    case = json.loads(Path(case_path).read_text())
    density = np.load(Path(case_path).parent.parent / case["volume"]["npy"])  # [z][y][x]
    return case, density


def mitsuba_worker(args):
    """Runs in the Mitsuba venv: renders every budget, writes <out>/mi_<spp>.npy, prints JSON."""
    import mitsuba as mi

    variant = args.variant
    try:
        mi.set_variant(variant)
    except Exception:  # no LLVM: the scalar variant
        variant = "scalar_rgb"
        mi.set_variant(variant)
    case, density = load_case(args.case)
    T = mi.ScalarTransform4f
    v, m, s, c = case["volume"], case["medium"], case["sun"], case["camera"]
    lo, hi = v["aabb_min"], v["aabb_max"]
    size = [hi[i] - lo[i] for i in range(3)]
    centre = [0.5 * (hi[i] + lo[i]) for i in range(3)]
    grid = mi.VolumeGrid(np.ascontiguousarray(density[..., None], dtype=np.float32))
    d = s["direction_to_sun"]

    def scene(spp, seed):
        return mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1000},
            "sensor": {
                "type": "perspective", "fov": c["vfov_deg"], "fov_axis": "y",
                "to_world": T().look_at(origin=c["origin"], target=c["target"], up=c["up"]),
                "film": {"type": "hdrfilm", "width": c["width"], "height": c["height"],
                         "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            },
            "sun": {"type": "directional", "direction": [-d[0], -d[1], -d[2]],
                    "irradiance": {"type": "rgb", "value": s["irradiance"]}},
            "cloud": {
                "type": "cube", "to_world": T().translate(centre).scale([0.5 * x for x in size]),
                "bsdf": {"type": "null"},
                "interior": {
                    "type": "heterogeneous", "albedo": m["albedo"], "scale": v["density_scale"],
                    "phase": {"type": "hg", "g": m["phase"]["g"]},
                    "sigma_t": {"type": "gridvolume", "grid": grid, "filter_type": "trilinear",
                                "to_world": T().translate(lo).scale(size)},
                },
            },
        })

    np.asarray(mi.render(scene(4, 1)))  # warm-up: compiles the kernels
    for spp in args.spp:
        sc = scene(spp, args.seed)
        t0 = time.perf_counter()
        img = np.asarray(mi.render(sc))
        dt = time.perf_counter() - t0
        np.save(Path(args.out) / f"mi_{spp}.npy", img[..., :3].astype(np.float32))
        print(json.dumps({"renderer": f"Mitsuba {mi.__version__} {variant}", "spp": spp,
                          "seconds": dt}), flush=True)


def row(renderer, spp, seconds, metrics):
    """Time to 5 %: a budget already at or under it is an upper bound (its own time); above
    it, an unbiased estimator's error ∝ spp^-1/2 extrapolates (RPNN's is not: its floor is the
    network's bias, so no extrapolation)."""
    e = metrics["rel_rmse_cloud_4x4"]
    t5 = seconds if e <= TARGET else (None if "rpnn" in renderer else seconds * (e / TARGET) ** 2)
    return {"renderer": renderer, "spp": spp, "seconds": round(seconds, 3),
            "rel_rmse_4x4": e, "mean_ratio": metrics["mean_lum_ratio"],
            "t_to_5pct_s": t5, "reached": e <= TARGET}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default=str(REFS / "cases" / "cumulus_side.json"))
    ap.add_argument("--spp", type=int, nargs="+", default=[256, 1024])
    ap.add_argument("--rpnn-spp", type=int, nargs="*", default=[4, 16])
    ap.add_argument("--seed", type=int, default=99)
    ap.add_argument("--mitsuba-python", help="the Python of a venv with mitsuba (else no Mitsuba)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        return mitsuba_worker(a)

    import nimbus

    case, density = load_case(a.case)
    name = Path(a.case).stem
    ref = REFS / f"{name}.exr"
    mask = np.load(REFS / f"{name}_tau.npy") >= 0.1
    v, m, s, c = case["volume"], case["medium"], case["sun"], case["camera"]
    scene = nimbus.Scene(
        volume=nimbus.Volume.from_numpy(density, aabb_min=v["aabb_min"], aabb_max=v["aabb_max"]),
        density_scale=v["density_scale"], albedo=m["albedo"],
        phase=nimbus.HenyeyGreenstein(m["phase"]["g"]),
        sun=nimbus.Sun(direction=s["direction_to_sun"], irradiance=s["irradiance"]),
        camera=nimbus.Camera(origin=c["origin"], target=c["target"], up=c["up"],
                             vfov_deg=c["vfov_deg"], width=c["width"], height=c["height"]))
    rows = []
    for method, spps in [("pt", a.spp), ("rpnn", a.rpnn_spp)]:
        for spp in spps:
            t0 = time.perf_counter()
            img = nimbus.render(scene, method, spp=spp, seed=a.seed)
            dt = time.perf_counter() - t0
            rows.append(row(f"Nimbus {method}", spp, dt, nimbus.compare(img, ref, mask=mask)))
            print(json.dumps(rows[-1]), flush=True)
    if a.mitsuba_python:
        with tempfile.TemporaryDirectory() as tmp:
            p = subprocess.run([a.mitsuba_python, __file__, "--worker", "--case", a.case,
                                "--out", tmp, "--seed", str(a.seed), "--variant", a.variant,
                                "--spp", *map(str, a.spp)],
                               capture_output=True, text=True, env=dict(os.environ))
            if p.returncode != 0:
                sys.exit(f"Mitsuba worker failed:\n{p.stderr}")
            for line in p.stdout.splitlines():
                r = json.loads(line)
                img = np.load(Path(tmp) / f"mi_{r['spp']}.npy")
                rows.append(row(r["renderer"], r["spp"], r["seconds"],
                                nimbus.compare(img, ref, mask=mask)))
                print(json.dumps(rows[-1]), flush=True)
    print("\n| renderer | spp | seconds | rel. RMSE 4x4 | mean ratio | time to 5 % (s) |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        t5 = ("–" if r["t_to_5pct_s"] is None else
              f"≤ {r['t_to_5pct_s']:.1f}" if r["reached"] else f"≈ {r['t_to_5pct_s']:.1f}")
        print(f"| {r['renderer']} | {r['spp']} | {r['seconds']:.2f} | {100 * r['rel_rmse_4x4']:.2f} % "
              f"| {r['mean_ratio']:.3f} | {t5} |")


if __name__ == "__main__":
    main()
