#!/usr/bin/python3
"""Writes far_tiles.vdb with Debian's official OpenVDB bindings (python3-openvdb, pyopenvdb):
two active 8^3 blocks of density 1 at index (0,0,0) and (1280,1280,1280). The file is 11 kB;
densified, its index box is 1288^3 voxels = 8.0 GiB of float32 (the memory-budget test)."""

import sys

import pyopenvdb as vdb

g = vdb.FloatGrid(0.0)
g.name = "density"
g.gridClass = vdb.GridClass.FOG_VOLUME
g.fill((0, 0, 0), (7, 7, 7), 1.0, True)
g.fill((1280, 1280, 1280), (1287, 1287, 1287), 1.0, True)
vdb.write(sys.argv[1] if len(sys.argv) > 1 else "far_tiles.vdb", grids=[g])
