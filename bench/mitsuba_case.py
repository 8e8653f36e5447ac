#!/usr/bin/env python3
"""Render a shared/refs case with Mitsuba 3 (the peer renderer) for side-by-side timing.

  DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \
  python3 bench/mitsuba_case.py ../shared/refs/cases/cumulus_side.json --spp 256 --out out/mi.exr

Needs `pip install mitsuba==3.9.1` and Debian `libllvm19` (LLVM 15 aborts). Prints one JSON line:
spp, wall seconds of the render (after a small warm-up render that compiles the kernels), and
camera paths per second. Compare the EXR with `nimbus compare out/mi.exr ../shared/refs/<case>.exr`.
"""
import argparse
import json
import os
import time

import mitsuba as mi


def build(case, case_dir, spp, seed):
    T = mi.ScalarTransform4f
    v, m, s, c = case["volume"], case["medium"], case["sun"], case["camera"]
    lo, hi = v["aabb_min"], v["aabb_max"]
    size = [hi[i] - lo[i] for i in range(3)]
    centre = [0.5 * (hi[i] + lo[i]) for i in range(3)]
    phase = {"type": "isotropic"} if m["phase"]["g"] == 0 else {"type": "hg", "g": m["phase"]["g"]}
    d = s["direction_to_sun"]
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1000},
        "sensor": {
            "type": "perspective",
            "fov": c["vfov_deg"],
            "fov_axis": "y",
            "to_world": T().look_at(origin=c["origin"], target=c["target"], up=c["up"]),
            "film": {
                "type": "hdrfilm",
                "width": c["width"],
                "height": c["height"],
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        },
        "sun": {
            "type": "directional",
            "direction": [-d[0], -d[1], -d[2]],
            "irradiance": {"type": "rgb", "value": s["irradiance"]},
        },
        "cloud": {
            "type": "cube",
            "to_world": T().translate(centre).scale([0.5 * x for x in size]),
            "bsdf": {"type": "null"},
            "interior": {
                "type": "heterogeneous",
                "albedo": m["albedo"],
                "scale": v["density_scale"],
                "phase": phase,
                "sigma_t": {
                    "type": "gridvolume",
                    "filename": os.path.join(case_dir, v["file"]),
                    "filter_type": "trilinear",
                    "to_world": T().translate(lo).scale(size),
                },
            },
        },
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("case")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default="out/mitsuba.exr")
    a = ap.parse_args()
    mi.set_variant(a.variant)
    case = json.load(open(a.case))
    case_dir = os.path.join(os.path.dirname(os.path.abspath(a.case)), "..")
    warm = mi.load_dict(build(case, case_dir, 4, a.seed + 1))
    mi.render(warm).numpy()
    scene = mi.load_dict(build(case, case_dir, a.spp, a.seed))
    t0 = time.perf_counter()
    img = mi.render(scene)
    arr = img.numpy()  # forces evaluation
    dt = time.perf_counter() - t0
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    mi.util.write_bitmap(a.out, img)
    c = case["camera"]
    paths = c["width"] * c["height"] * a.spp
    print(json.dumps({"renderer": f"mitsuba {mi.__version__} {a.variant}", "spp": a.spp,
                      "seconds": round(dt, 3), "paths_per_s": paths / dt, "shape": list(arr.shape)}))


if __name__ == "__main__":
    main()
