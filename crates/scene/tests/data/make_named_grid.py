#!/usr/bin/python3
"""Writes smoke_grid.vdb with Debian's official OpenVDB bindings (python3-openvdb, pyopenvdb): a
fog volume named `smoke` (no `density` grid), a 6^3 block of value 0.5 at index (2,2,2), and a
second float grid `temperature`. Tests read it by name (`grid = "smoke"`)."""

import sys

import pyopenvdb as vdb

smoke = vdb.FloatGrid(0.0)
smoke.name = "smoke"
smoke.gridClass = vdb.GridClass.FOG_VOLUME
smoke.fill((2, 2, 2), (7, 7, 7), 0.5, True)
temp = vdb.FloatGrid(0.0)
temp.name = "temperature"
temp.fill((0, 0, 0), (3, 3, 3), 300.0, True)
vdb.write(sys.argv[1] if len(sys.argv) > 1 else "smoke_grid.vdb", grids=[smoke, temp])
