#!/usr/bin/env bash
# Writes the OpenVDB / NanoVDB codec fixtures with the official OpenVDB 10 tools from Debian
# (python3-openvdb for the grid and its dense array, libopenvdb-tools' vdb_tool for the codecs)
# and, for zlib (vdb_tool 10.6's codec=zip writes active-mask compression only), the
# independent writer tinyvdb from PyPI; the official library reads every file back and must
# find the same values:
#   cloud_{none,active,blosc}.vdb       full floats: no compression, active mask, Blosc + mask
#   cloud_zip.vdb / cloud_zip_full.vdb  full floats: zlib + active mask / zlib alone (tinyvdb)
#   cloud_half.vdb                      half floats (saveFloatAsHalf), Blosc
#   cloud.nvdb / cloud_none.nvdb        NanoVDB Float grid, zlib / uncompressed
#   cloud_blosc.nvdb                    NanoVDB Float grid, Blosc
#   cloud_fp{16,8,4}.nvdb               NanoVDB quantised grids (16/8/4-bit codes per leaf),
#                                       zlib / Blosc / zlib
#   cloud_full.nvdb, cloud_fp4_full.nvdb  Float / Fp4 with full checksums (zlib)
#   cloud_dense.npy                     the writer's own dense array over the active bounding box
# The grid: a soft sphere of 4 207 active voxels around index (45, 53, 50) plus an active 8³
# block at (64..71)³ that OpenVDB stores as a tile; voxel size 0.02.
set -euo pipefail
cd "$(dirname "$0")"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
/usr/bin/python3 - "$tmp/base.vdb" <<'PY'
import sys
import numpy as np
import pyopenvdb as vdb

g = vdb.FloatGrid(0.0)
g.name = "density"
g.gridClass = vdb.GridClass.FOG_VOLUME
acc = g.getAccessor()
c = np.array([45.0, 53.0, 50.0])
r = 9.5
for x in range(34, 56):
    for y in range(42, 64):
        for z in range(39, 61):
            d = np.linalg.norm(np.array([x, y, z]) - c)
            if d < r:
                v = 0.25 + 0.75 * (1 - d / r) + 0.01 * ((x * 7 + y * 3 + z) % 5)
                acc.setValueOn((x, y, z), float(v))
g.fill((64, 64, 64), (71, 71, 71), 0.5, True)
g.transform = vdb.createLinearTransform(voxelSize=0.02)
lo, hi = g.evalActiveVoxelBoundingBox()
assert (lo, hi) == ((36, 44, 41), (71, 71, 71)), (lo, hi)
dense = np.zeros([h - l + 1 for l, h in zip(lo, hi)], dtype=np.float32)
g.copyToArray(dense, ijk=lo)
# (x, y, z) -> stored z-major like the renderer's grids: shape (nz, ny, nx)
np.save("cloud_dense.npy", np.ascontiguousarray(dense.transpose(2, 1, 0)))
vdb.write(sys.argv[1], grids=[g])
PY
for codec in none active blosc; do
  vdb_tool -read "$tmp/base.vdb" -write codec=$codec bits=32 cloud_$codec.vdb >/dev/null
done
python3 -m venv "$tmp/venv"
"$tmp/venv/bin/pip" install -q tinyvdb==0.9.0 numpy
"$tmp/venv/bin/python" - "$tmp/base.vdb" <<'PY'
import sys
import tinyvdb

for name, flags in [("cloud_zip.vdb", 3), ("cloud_zip_full.vdb", 1)]:
    f = tinyvdb.open(sys.argv[1])
    f.read_grids()
    f.save(name, compression=flags)
PY
vdb_tool -read "$tmp/base.vdb" -write codec=blosc bits=16 cloud_half.vdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=32 cloud.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=none bits=32 cloud_none.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=blosc bits=32 cloud_blosc.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=16 cloud_fp16.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=blosc bits=8 cloud_fp8.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=4 cloud_fp4.nvdb >/dev/null
# Full checksums (head and nodes; the tools' default is the head alone).
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=32 checksum=full cloud_full.nvdb >/dev/null
vdb_tool -read "$tmp/base.vdb" -write codec=zip bits=4 checksum=full cloud_fp4_full.nvdb >/dev/null
OPENVDB_DISABLE_DELAYED_LOAD=1 /usr/bin/python3 - "$tmp/base.vdb" cloud_*.vdb <<'PY'
import sys
import numpy as np
import pyopenvdb as vdb

base = vdb.read(sys.argv[1], "density")
lo, hi = base.evalActiveVoxelBoundingBox()
want = np.zeros([h - l + 1 for l, h in zip(lo, hi)], dtype=np.float32)
base.copyToArray(want, ijk=lo)
for name in sys.argv[2:]:
    g = vdb.read(name, "density")
    got = np.zeros_like(want)
    g.copyToArray(got, ijk=lo)
    tol = 1e-3 if "half" in name else 0.0
    assert np.allclose(got, want, rtol=tol, atol=0), name
    assert g.evalActiveVoxelBoundingBox() == (lo, hi), name
    print("checked with libopenvdb:", name)
PY
ls -l cloud*
