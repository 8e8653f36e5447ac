"""Nimbus quick start: a numpy density → pt and rpnn images → compare → PNG (docs/python.md).

Run: python examples/python/quickstart.py [OUT_DIR]
"""
import sys
from pathlib import Path

import numpy as np

import nimbus

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/python")
out.mkdir(parents=True, exist_ok=True)

# A soft ball of cloud, indexed [z][y][x].
z, y, x = np.mgrid[-1:1:24j, -1:1:18j, -1:1:24j]
density = np.clip(1.0 - np.sqrt(x**2 + (y / 0.75) ** 2 + z**2), 0.0, None) * 2.0

vol = nimbus.Volume.from_numpy(density, aabb_min=(-1, -0.75, -1), aabb_max=(1, 0.75, 1))
scene = nimbus.Scene(volume=vol, density_scale=20.0, albedo=1.0,
                     phase=nimbus.HenyeyGreenstein(0.857),
                     sun=nimbus.Sun(direction=(1, 0.35, -0.1), irradiance=(1, 1, 1)),
                     sky=nimbus.Sky(radiance=(0.03, 0.045, 0.075)),
                     camera=nimbus.Camera(origin=(0, 0.1, 4.2), target=(0, 0, 0), up=(0, 1, 0),
                                          vfov_deg=30.0, width=64, height=48))
pt = nimbus.render(scene, method="pt", spp=64, seed=7)
rpnn = nimbus.render(scene, method="rpnn", spp=4, seed=7, backend="ort")
metrics = nimbus.compare(rpnn, pt, mask=nimbus.tau(scene) >= 0.1)
pt.save(out / "pt.png")
rpnn.save(out / "rpnn.png")
print(f"pt {pt.seconds:.2f} s, rpnn {rpnn.seconds:.2f} s; rpnn against pt: "
      f"4x4 error {metrics['rel_rmse_cloud_4x4']:.3f}, mean ratio {metrics['mean_lum_ratio']:.3f}")
