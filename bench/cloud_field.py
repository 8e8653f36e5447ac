"""A field of small clouds in a large box (BENCHMARKS.md "Final gathering", "Volumes at scale"):
13 copies of one generated 64x40x64 cumulus in a 384x40x384 grid (3.9 % of the voxels
non-zero), written as .npy with a scene file lit by a low sun and seen from above.

Usage: training/.venv/bin/python bench/cloud_field.py CLOUD.npy OUT_DIR
(CLOUD.npy from `nimbus generate cumulus --seed 3 --res 64,40,64 --out CLOUD.npy`)
"""

import sys
from pathlib import Path

import numpy as np

# Cloud corners (x, z) in voxels: a loose 5-4-4 arrangement without overlaps.
CORNERS = [
    (0, 0), (80, 8), (160, 0), (240, 12), (320, 4),
    (40, 96), (120, 104), (200, 96), (280, 108),
    (8, 200), (96, 210), (184, 198), (272, 206),
]


def main():
    cloud = np.load(sys.argv[1]).astype(np.float32)  # (z, y, x)
    out = Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    nz, ny, nx = cloud.shape
    field = np.zeros((384, ny, 384), np.float32)
    for x, z in CORNERS:
        field[z:z + nz, :, x:x + nx] = np.maximum(field[z:z + nz, :, x:x + nx], cloud)
    np.save(out / "field.npy", field)
    (out / "field.toml").write_text(f"""[volume]
file = "field.npy"
aabb_min = [-4.8, -0.25, -4.8]
aabb_max = [4.8, 0.25, 4.8]
density_scale = 60.0
albedo = 1.0
phase = {{ kind = "hg", g = 0.857 }}

[sun]
direction = [0.5, 0.6, 0.3]
irradiance = [3.0, 3.0, 3.0]

[camera]
origin = [0.0, 6.0, 9.0]
target = [0.0, 0.0, 0.0]
vfov_deg = 50.0
width = 160
height = 100

[render]
spp = 16
seed = 1
""")
    print(f"{out / 'field.npy'}: {np.count_nonzero(field) / field.size:.1%} of the voxels non-zero")


if __name__ == "__main__":
    main()
