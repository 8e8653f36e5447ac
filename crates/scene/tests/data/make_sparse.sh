#!/usr/bin/env bash
# Writes a sparse fixture with the official OpenVDB 10 tools from Debian (python3-openvdb,
# libopenvdb-tools): two small fog spheres ≈ 1 680 voxels apart on each axis and an active 16³ block that
# OpenVDB stores as 8³ tiles, in a 1691³ index box — 4.8 G voxels (more than 2^32),
# 19 GB if it were dense; a few kB on disk:
#   far_spheres.vdb    full floats, Blosc
#   far_spheres.nvdb   NanoVDB Float grid, zlib
#   far_spheres.json   what libopenvdb reads: bounding box, active voxel count, value sum and
#                      probe voxels (index relative to the box's minimum corner)
set -euo pipefail
cd "$(dirname "$0")"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
/usr/bin/python3 - "$tmp/base.vdb" <<'PY'
import json
import sys
import numpy as np
import pyopenvdb as vdb

g = vdb.FloatGrid(0.0)
g.name = "density"
g.gridClass = vdb.GridClass.FOG_VOLUME
acc = g.getAccessor()
for c in [(10, 10, 10), (1690, 1690, 1690)]:
    r = 6.0
    for x in range(c[0] - 6, c[0] + 7):
        for y in range(c[1] - 6, c[1] + 7):
            for z in range(c[2] - 6, c[2] + 7):
                d = np.linalg.norm(np.array([x, y, z], dtype=float) - c)
                if d < r:
                    acc.setValueOn((x, y, z), float(0.2 + 0.8 * (1 - d / r)))
g.fill((800, 400, 800), (815, 415, 815), 0.5, True)
g.transform = vdb.createLinearTransform(voxelSize=0.001)
lo, hi = g.evalActiveVoxelBoundingBox()
total = 0.0
for it in g.citerOnValues():
    n = (it.max[0] - it.min[0] + 1) * (it.max[1] - it.min[1] + 1) * (it.max[2] - it.min[2] + 1)
    total += it.value * n
probes = []
for p in [(10, 10, 10), (12, 9, 11), (1690, 1690, 1690), (1687, 1693, 1689), (808, 405, 811),
          (500, 500, 500), (6, 6, 6)]:
    probes.append([p[0] - lo[0], p[1] - lo[1], p[2] - lo[2], acc.getValue(p)])
json.dump({"lo": lo, "hi": hi, "active": g.activeVoxelCount(), "sum": total,
           "probes": probes}, open("far_spheres.json", "w"), indent=1)
vdb.write(sys.argv[1], grids=[g])
PY
vdb_tool -read "$tmp/base.vdb" -write codec=blosc bits=32 far_spheres.vdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=32 far_spheres.nvdb >/dev/null
ls -l far_spheres*
