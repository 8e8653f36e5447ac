#!/usr/bin/env python3
"""Writes cloud_v32_6.nvdb and cloud_v32_7.nvdb: the grid of cloud_none.nvdb (OpenVDB 10's
vdb_tool, NanoVDB 32.4.2) relabelled as written by NanoVDB 32.6.0 (OpenVDB 11) and 32.7.0
(OpenVDB 12), with full checksums computed here by those versions' rules, zlib-coded. No file
written by OpenVDB 11 or 12 is at hand, so this independent implementation (zlib's CRC-32,
from NanoVDB's util/GridChecksum.h at v11.0.0 and tools/GridChecksum.h at v12.0.0) is what the
reader's `nvdb/checksum.rs` is checked against.

- 32.6: head = CRC-32 of grid bytes [16, first upper node); tail = blocked CRC of the rest.
- 32.7+: head = CRC-32 of [16, 736) (GridData and TreeData); tail = blocked CRC of the rest.
- Blocked CRC: 4 KiB blocks, the remainder joined to the last; the CRC of the blocks' CRCs as
  little-endian u32.

Run: python3 crates/scene/tests/data/make_checksums.py   (standard library only)."""

import pathlib
import struct
import zlib

HERE = pathlib.Path(__file__).resolve().parent


def blocked(b):
    n = len(b) // 4096
    crcs = [zlib.crc32(b[i * 4096 : len(b) if i + 1 == n else (i + 1) * 4096]) for i in range(n)]
    return zlib.crc32(struct.pack(f"<{n}I", *crcs))


src = (HERE / "cloud_none.nvdb").read_bytes()
(grid_size, file_size) = struct.unpack_from("<qq", src, 16)
(name_size,) = struct.unpack_from("<I", src, 16 + 136)
start = 16 + 176 + name_size
grid = bytearray(src[start : start + grid_size])
assert len(src) == start + grid_size and grid[:8] == b"NanoVDB0"
for minor, name in [(6, "cloud_v32_6.nvdb"), (7, "cloud_v32_7.nvdb")]:
    g = bytearray(grid)
    version = 32 << 21 | minor << 10
    struct.pack_into("<I", g, 16, version)
    if minor == 6:
        (upper,) = struct.unpack_from("<q", g, 672 + 16)
        mid = 672 + upper
    else:
        mid = 672 + 64
    struct.pack_into("<II", g, 8, zlib.crc32(g[16:mid]), blocked(bytes(g[mid:])))
    z = zlib.compress(bytes(g), 9)
    head = bytearray(src[:start])
    struct.pack_into("<I", head, 8, version)  # the segment's version
    struct.pack_into("<q", head, 24, 8 + len(z))  # the grid's file size
    # The grid's metadata: codec (u16 at 168: zlib), then padding and the version (u32 at 172).
    struct.pack_into("<H", head, 16 + 168, 1)
    struct.pack_into("<I", head, 16 + 172, version)
    struct.pack_into("<H", head, 14, 1)  # the segment's codec
    out = bytes(head) + struct.pack("<q", len(z)) + z
    (HERE / name).write_bytes(out)
    print(f"{name}: {len(out)} bytes")
