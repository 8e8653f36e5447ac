#!/usr/bin/env python3
"""Writes the bad-input regression files (issue: no file or flag may abort, hang or silently
corrupt). Each file is small and derived from a valid one; `cases.toml` says what `nimbus` must
do with it (exit code, message, time) and `crates/cli/tests/bad_inputs.rs` checks that.

Run from anywhere: python3 crates/cli/tests/bad-inputs/make.py   (standard library only)."""

import pathlib
import struct
import zlib

HERE = pathlib.Path(__file__).resolve().parent
DATA = HERE.parent.parent.parent / "scene" / "tests" / "data"
OUT = HERE / "files"
OUT.mkdir(exist_ok=True)


def write(name, data):
    (OUT / name).write_bytes(data)
    print(f"{name}: {len(data)} bytes")


# 1. A compressed-block length of 2^40 in a Blosc leaf buffer (once an allocator abort).
b = bytearray((DATA / "cloud_blosc.vdb").read_bytes())
# The last leaf buffer: its value mask (64 bytes), metadata byte, then the i64 block length.
# Found by scanning back from the end for a positive length that spans exactly to the end.
for at in range(len(b) - 16, 0, -1):
    (k,) = struct.unpack_from("<q", b, at)
    if 16 <= k and at + 8 + k == len(b):
        break
else:
    raise SystemExit("no final Blosc block found")
struct.pack_into("<q", b, at, 1 << 40)
write("block_length_2e40.vdb", bytes(b))

# 2. A truncated OpenVDB file (once "header: IoError").
b = (DATA / "cloud_zip.vdb").read_bytes()
write("truncated.vdb", b[: len(b) * 2 // 3])

# 3. A NanoVDB grid whose root child offset points back at the grid (a cycle), re-compressed:
#    with its checksum disabled (all ones), so that the tree walk meets the cycle, and, as
#    damaged_root.nvdb, with the checksum the writer stored, which no longer matches.
b = bytearray((DATA / "cloud.nvdb").read_bytes())
(grid_size, file_size) = struct.unpack_from("<qq", b, 16)
(n,) = struct.unpack_from("<q", b, 200)
assert file_size == 8 + n == len(b) - 200
g = bytearray(zlib.decompress(bytes(b[208:208 + n])))
assert len(g) == grid_size
root = 672 + 64
struct.pack_into("<q", g, root + 64 + 8, -root)
for name, checksum in [("damaged_root.nvdb", None), ("cyclic_root.nvdb", b"\xff" * 8)]:
    if checksum:
        g[8:16] = checksum
    z = zlib.compress(bytes(g), 9)
    struct.pack_into("<q", b, 24, 8 + len(z))
    write(name, bytes(b[:200]) + struct.pack("<q", len(z)) + z)

# 4. A NanoVDB file that claims a 1 TB grid from a few zlib bytes.
b = bytearray((DATA / "cloud.nvdb").read_bytes())
struct.pack_into("<q", b, 16, 1 << 40)
write("huge_grid.nvdb", bytes(b))

# 5. An EXR whose data window claims 10^6 x 10^6 pixels: see cases.toml (made by the test
#    from a 4x3 image, as the EXR writer is the renderer's own).

# 6. Scenes with values whose derived quantities overflow.
SCENE = """[volume]
generator = {{ kind = "cumulus", seed = 1, resolution = [{res}] }}
aabb_min = [-1.0, -0.5, -1.0]
aabb_max = [1.0, 0.5, 1.0]
density_scale = {scale}
albedo = 0.99
phase = {{ kind = "hg", g = 0.857 }}

[sun]
direction = [0.3, 0.8, 0.5]
irradiance = [{sun}, {sun}, {sun}]
{extra}
[camera]
origin = [{origin}]
target = [{target}]
up = [0.0, 1.0, 0.0]
vfov_deg = 40.0
width = 16
height = 12

[render]
spp = 2
seed = 0
"""


def scene(name, res="16, 12, 16", scale="40.0", sun="3.0", origin="0.0, 0.3, 4.0",
          target="0.0, 0.0, 0.0", extra=""):
    text = SCENE.format(res=res, scale=scale, sun=sun, origin=origin, target=target,
                        extra=extra)
    write(name, text.encode())


scene("density_1e20.toml", scale="1e20")
scene("camera_1e308.toml", origin="1e308, 0.0, 0.0", target="-1e308, 0.0, 0.0")
scene("sun_1e308.toml", sun="1e308")
scene("sky_1e39.toml", extra="\n[sky]\nradiance = [1e39, 1e39, 1e39]\n")
scene("sun_disc_1e-300.toml", extra="angular_radius_deg = 1e-300\n")
scene("generator_1290.toml", res="1290, 1290, 1290")
scene("good.toml")

# 7. A scene modelled at 10^34 (box ±10^34, density scale 10^-34): right in f64, once black or
#    cloudless without a word in the f32 estimators. And a depth limit that pm and RPNN, which
#    compute every order of scattering, cannot honour.
text = SCENE.format(res="16, 12, 16", scale="1e-34", sun="3.0", origin="0.0, 3e33, 4e34",
                    target="0.0, 0.0, 0.0", extra="")
text = text.replace("aabb_min = [-1.0, -0.5, -1.0]", "aabb_min = [-1e34, -5e33, -1e34]")
text = text.replace("aabb_max = [1.0, 0.5, 1.0]", "aabb_max = [1e34, 5e33, 1e34]")
write("scale_1e34.toml", text.encode())
text = SCENE.format(res="16, 12, 16", scale="40.0", sun="3.0", origin="0.0, 0.3, 4.0",
                    target="0.0, 0.0, 0.0", extra="")
write("max_depth_0.toml", text.replace("seed = 0", "seed = 0\nmax_depth = 0").encode())
