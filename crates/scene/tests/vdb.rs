//! The OpenVDB reader against files written by the official OpenVDB 10 tools
//! (`tests/data/make_codecs.sh`: python3-openvdb and vdb_tool from Debian), compared value by
//! value with the writer's own dense array; and on truncated, mutated and crafted files.

use std::path::{Path, PathBuf};

use nimbus_scene::io;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The writer's dense array over the active bounding box, indexed [z][y][x].
fn dense() -> (Vec<f32>, [usize; 3]) {
    let f = io::read_grid(data("cloud_dense.npy")).unwrap();
    let res = f.grid.res();
    let mut v = Vec::new();
    for z in 0..res[2] {
        for y in 0..res[1] {
            for x in 0..res[0] {
                v.push(f.grid.get(x, y, z));
            }
        }
    }
    (v, res)
}

fn values(f: &io::GridFile) -> Vec<f32> {
    let res = f.grid.res();
    let mut v = Vec::new();
    for z in 0..res[2] {
        for y in 0..res[1] {
            for x in 0..res[0] {
                v.push(f.grid.get(x, y, z));
            }
        }
    }
    v
}

/// `n` copies of `bytes` with one to four bytes changed each, from a fixed-seed LCG.
fn mutants(bytes: &[u8], seed: u64, n: usize) -> impl Iterator<Item = Vec<u8>> + '_ {
    let mut state = seed;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 33) as usize
    };
    (0..n).map(move |_| {
        let mut m = bytes.to_vec();
        for _ in 0..1 + next() % 4 {
            let i = next() % m.len();
            m[i] = next() as u8;
        }
        m
    })
}

#[test]
fn every_codec_reads_the_writers_values() {
    let (want, res) = dense();
    assert_eq!(res, [36, 28, 31]);
    assert_eq!(want.iter().filter(|v| **v > 0.0).count(), 4207);
    for (file, half) in [
        ("cloud_none.vdb", false),
        ("cloud_zip.vdb", false),
        ("cloud_zip_full.vdb", false),
        ("cloud_blosc.vdb", false),
        ("cloud_active.vdb", false),
        ("cloud_half.vdb", true),
    ] {
        let f = io::read_grid(data(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(f.grid.res(), res, "{file}");
        let got = values(&f);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            // Full floats are exact; half floats are the writer's values rounded to binary16
            // (round to nearest even, as OpenVDB's `Half`), so exact after the same rounding.
            let w = if half {
                half::f16::from_f32(*w).to_f32()
            } else {
                *w
            };
            assert_eq!(*g, w, "{file}: value {i}");
        }
        // Index box (36, 44, 41)–(71, 71, 71), voxel size 0.02, voxel centres on integers.
        let (lo, hi) = f.bounds.unwrap();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(lo.x, 35.5 * 0.02) && close(lo.y, 43.5 * 0.02) && close(lo.z, 40.5 * 0.02));
        assert!(close(hi.x, 71.5 * 0.02) && close(hi.y, 71.5 * 0.02) && close(hi.z, 71.5 * 0.02));
    }
}

#[test]
fn small_half_float_file() {
    // half_density.vdb (pyopenvdb, saveFloatAsHalf): voxels (0,0,0) = 0.5 and (1,0,0) = 2.0,
    // voxel size 1, as pyopenvdb itself reads them back. Its upper and lower nodes store no
    // values at all (the half writer skips empty arrays, length included).
    let f = io::read_grid(data("half_density.vdb")).unwrap();
    assert_eq!(f.grid.res(), [2, 1, 1]);
    assert_eq!((f.grid.get(0, 0, 0), f.grid.get(1, 0, 0)), (0.5, 2.0));
    let (lo, hi) = f.bounds.unwrap();
    assert_eq!((lo.to_array(), hi.to_array()), ([-0.5; 3], [1.5, 0.5, 0.5]));
}

#[test]
fn sparse_view_keeps_tiles_and_leaves() {
    let bytes = std::fs::read(data("cloud_blosc.vdb")).unwrap();
    let s = io::vdb::read_sparse(&bytes, "density").unwrap();
    // The 8³ block at (64..71)³ is stored as one active tile of a lower internal node.
    assert_eq!(s.tree.tiles.len(), 1);
    assert_eq!(s.tree.tiles[0].origin, [64, 64, 64]);
    assert_eq!((s.tree.tiles[0].dim, s.tree.tiles[0].value), (8, 0.5));
    let active: u32 = s
        .tree
        .leaves
        .iter()
        .map(|l| l.mask.iter().map(|w| w.count_ones()).sum::<u32>())
        .sum();
    assert_eq!(active, 4207 - 512);
    assert_eq!(io::vdb::grid_names(&bytes).unwrap(), vec!["density"]);
}

/// Every prefix and many byte mutations of real files: an error or a grid, never a panic, an
/// abort or a hang. The file is parsed from memory (no disk I/O per case).
#[test]
fn truncated_and_mutated_files_fail_cleanly() {
    // A mutated origin can spread the active voxels over a huge box; the budget refuses it
    // before the dense grid is allocated (this test binary's process only).
    nimbus_scene::memory::set_budget(64 << 20);
    let p = Path::new("m.vdb");
    for file in [
        "cloud_zip.vdb",
        "cloud_blosc.vdb",
        "cloud_half.vdb",
        "small_density.vdb",
    ] {
        let bytes = std::fs::read(data(file)).unwrap();
        // Prefixes: every length below 512 bytes, then every 97th.
        for cut in (0..bytes.len()).filter(|c| *c < 512 || c % 97 == 0) {
            let e = io::vdb::parse(&bytes[..cut], p).expect_err("a prefix must fail");
            let e = e.to_string();
            assert!(
                e.contains("m.vdb") && e.contains("field"),
                "{file} cut {cut}: {e}"
            );
        }
        // Deterministic mutations: one to four bytes changed per case.
        for m in mutants(&bytes, 0x2545_f491_4f6c_dd1du64, 1500) {
            let _ = io::vdb::parse(&m, p);
        }
    }
}

#[test]
fn crafted_lengths_are_refused_by_offset() {
    nimbus_scene::memory::set_budget(64 << 20);
    // A 2^40 compressed-block length (the third-party reader used before aborted on it) written
    // over every position of the second half of the file: the reader refuses it without allocating.
    let bytes = std::fs::read(data("cloud_zip.vdb")).unwrap();
    let p = Path::new("crafted.vdb");
    let mut refused = 0;
    let mut named = 0;
    for i in bytes.len() / 2..bytes.len() - 8 {
        let mut m = bytes.clone();
        m[i..i + 8].copy_from_slice(&(1i64 << 40).to_le_bytes());
        if let Err(e) = io::vdb::parse(&m, p) {
            let e = e.to_string();
            assert!(e.contains("crafted.vdb") && e.contains("byte"), "{e}");
            refused += 1;
            // Where it lands on a block length, the message names the claim and the offset.
            if e.contains("claims 1099511627776 bytes") && e.contains("leaf buffer") {
                named += 1;
            }
        }
    }
    assert!(refused > 1000 && named > 0, "{refused} {named}");
}

#[test]
fn nanovdb_grids_read_the_writers_values() {
    let (want, res) = dense();
    let range = 1.04f32 - 0.25;
    for (file, bits) in [
        ("cloud.nvdb", 32),
        ("cloud_none.nvdb", 32),
        ("cloud_blosc.nvdb", 32),
        ("cloud_fp16.nvdb", 16),
        ("cloud_fp8.nvdb", 8),
        ("cloud_fp4.nvdb", 4),
    ] {
        let f = io::read_grid(data(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(f.grid.res(), res, "{file}");
        // Float grids are exact. Quantised leaves store codes with a step
        // q = (max − min) / (2^bits − 1) per leaf, bounded by the whole grid's active range
        // (0.25 … 1.04). Rounding to the nearest code would give |error| ≤ q / 2; the writer's
        // Fp4 reaches 0.502 q, so the bound is one step (a misread code is off by ≥ q
        // and the wrong bit layout by far more).
        let tol = if bits == 32 {
            0.0
        } else {
            range / ((1u32 << bits) - 1) as f32
        };
        let mut worst = 0.0f32;
        for (i, (g, w)) in values(&f).iter().zip(&want).enumerate() {
            if *w == 0.0 {
                assert_eq!(*g, 0.0, "{file}: inactive value {i}");
            }
            worst = worst.max((g - w).abs());
        }
        assert!(worst <= tol, "{file}: worst error {worst} > {tol}");
        let (lo, hi) = f.bounds.unwrap();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(
            close(lo.x, 35.5 * 0.02) && close(hi.z, 71.5 * 0.02),
            "{file}"
        );
    }
    // The same grid through OpenVDB and NanoVDB: identical.
    let a = io::read_grid(data("cloud_blosc.vdb")).unwrap();
    let b = io::read_grid(data("cloud.nvdb")).unwrap();
    assert_eq!((a.grid, a.bounds), (b.grid, b.bounds));
}

/// Where the grid buffer of an uncompressed single-grid file named `density` starts: the
/// segment header (16 bytes), the grid's metadata (176) and its name (8 with the NUL).
const GRID: usize = 16 + 176 + 8;

/// A NanoVDB file of one grid, its buffer stored uncompressed: `file`'s grid as it is, or
/// changed by `edit`.
fn uncompressed(file: &str, edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    use std::io::Read;
    let b = std::fs::read(data(file)).unwrap();
    let grid_size = i64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    let codec = u16::from_le_bytes([b[14], b[15]]);
    let mut grid = if codec == 0 {
        b[GRID..].to_vec()
    } else {
        assert_eq!(codec, 1, "{file}: zlib-coded fixtures only");
        let mut g = Vec::new();
        flate2::read::ZlibDecoder::new(&b[GRID + 8..])
            .read_to_end(&mut g)
            .unwrap();
        g
    };
    assert_eq!(grid.len(), grid_size, "{file}");
    edit(&mut grid);
    let mut head = b[..GRID].to_vec();
    head[14..16].copy_from_slice(&0u16.to_le_bytes()); // the segment's codec: none
    head[24..32].copy_from_slice(&(grid.len() as i64).to_le_bytes()); // bytes in the file
    head[16 + 168..16 + 170].copy_from_slice(&0u16.to_le_bytes()); // the grid's codec: none
    head.extend_from_slice(&grid);
    head
}

/// NanoVDB checksums (`src/io/nvdb/checksum.rs`). Full checksums from OpenVDB 10's vdb_tool
/// (Float and Fp4, the 32.4 rules), and 32.6 / 32.7 files whose checksums
/// `tests/data/make_checksums.py` computed independently: each reads the grid of the file
/// without them, and one changed byte in the header, in the root or in a leaf's values is
/// refused naming the field. A partial checksum (the tools' default) covers the header and
/// root only; no checksum (all ones) checks nothing.
#[test]
fn nanovdb_checksums_refuse_damage() {
    let p = Path::new("m.nvdb");
    let want = io::read_grid(data("cloud_none.nvdb")).unwrap();
    let fp4 = io::read_grid(data("cloud_fp4.nvdb")).unwrap();
    let read = |b: &[u8]| io::nvdb::parse(b, p).map_err(|e| e.to_string());
    let refused = |r: Result<io::GridFile, String>, what: &str| {
        let Err(e) = r else { panic!("{what}: read") };
        assert!(
            e.contains("m.nvdb") && e.contains("grid.checksum"),
            "{what}: {e}"
        );
        assert!(e.contains("damaged"), "{what}: {e}");
    };
    // Byte 40: the grid's name; 736 + 70: the root's table; the last byte: a leaf's values.
    let flip = |at: usize| {
        move |g: &mut Vec<u8>| {
            let at = if at == usize::MAX { g.len() - 1 } else { at };
            g[at] ^= 0x10;
        }
    };
    for (file, same) in [
        ("cloud_full.nvdb", &want),
        ("cloud_fp4_full.nvdb", &fp4),
        ("cloud_v32_6.nvdb", &want),
        ("cloud_v32_7.nvdb", &want),
    ] {
        let f = io::read_grid(data(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!((&f.grid, f.bounds), (&same.grid, same.bounds), "{file}");
        assert!(read(&uncompressed(file, |_| ())).is_ok(), "{file}");
        for at in [40, 736 + 70, usize::MAX] {
            refused(
                read(&uncompressed(file, flip(at))),
                &format!("{file} byte {at}"),
            );
        }
        // Without the checksum the same damage is read (here: a leaf value).
        let unchecked = uncompressed(file, |g| {
            g[8..16].fill(0xff);
            flip(usize::MAX)(g)
        });
        assert!(read(&unchecked).is_ok(), "{file}");
    }
    // Hostile headers whose head CRC was recomputed after the change (so that the node ranges
    // and sizes are what the checksum code meets): an error, never a panic, except where the
    // field is one the reader does not use (32.7's upper-node offset: the tree is walked from
    // the root). The 32.4 head ends after the root's table, the 32.7 head at byte 736.
    let rehead = |g: &mut Vec<u8>, end: usize| {
        let c = crc32fast::hash(&g[16..end.min(g.len())]);
        g[8..12].copy_from_slice(&c.to_le_bytes());
    };
    let table = |g: &[u8]| u32::from_le_bytes(g[760..764].try_into().unwrap()) as usize;
    for (file, at, value, readable) in [
        ("cloud_full.nvdb", 704, u32::MAX as u64, false), // TreeData's leaf count
        ("cloud_full.nvdb", 688, (-1i64) as u64, false),  // the upper nodes' offset
        ("cloud_full.nvdb", 32, 1 << 40, false),          // GridData.mGridSize
        ("cloud_v32_7.nvdb", 704, u32::MAX as u64, false),
        ("cloud_v32_7.nvdb", 688, (-1i64) as u64, true),
        ("cloud_v32_7.nvdb", 32, 12345, false),
        ("cloud_v32_6.nvdb", 688, 0, false), // no upper node: the head covers the whole grid
    ] {
        let b = uncompressed(file, |g| {
            let end = if file == "cloud_v32_7.nvdb" {
                736
            } else {
                800 + 32 * table(g)
            };
            let end = if file == "cloud_v32_6.nvdb" {
                g.len()
            } else {
                end
            };
            let width = if at == 704 { 4 } else { 8 };
            g[at..at + width].copy_from_slice(&value.to_le_bytes()[..width]);
            rehead(g, end);
        });
        match read(&b) {
            Ok(f) => assert!(
                readable && f.grid == want.grid,
                "{file}: byte {at} = {value} read"
            ),
            Err(e) => assert!(!readable && e.contains("m.nvdb"), "{file} byte {at}: {e}"),
        }
    }
    // A root table that claims 2^32 - 1 tiles: the head's range leaves the grid.
    let b = uncompressed("cloud_full.nvdb", |g| g[760..764].fill(0xff));
    let e = read(&b).unwrap_err();
    assert!(
        e.contains("grid.checksum") && e.contains("outside the grid"),
        "{e}"
    );
    // Random damage to files with full checksums, by every rule.
    for file in ["cloud_full.nvdb", "cloud_v32_6.nvdb", "cloud_v32_7.nvdb"] {
        for m in mutants(&uncompressed(file, |_| ()), 0x6a09_e667_f3bc_c908u64, 300) {
            let _ = io::nvdb::parse(&m, p);
        }
    }
    // A partial checksum: header and root damage is refused, a leaf's values are not covered.
    refused(
        read(&uncompressed("cloud_none.nvdb", flip(40))),
        "partial, name",
    );
    refused(
        read(&uncompressed("cloud_none.nvdb", flip(736 + 70))),
        "partial, root",
    );
    assert!(read(&uncompressed("cloud_none.nvdb", flip(usize::MAX))).is_ok());
}

#[test]
fn nanovdb_damage_fails_cleanly() {
    nimbus_scene::memory::set_budget(64 << 20);
    let p = Path::new("m.nvdb");
    for file in [
        "cloud.nvdb",
        "cloud_blosc.nvdb",
        "cloud_none.nvdb",
        "cloud_fp4.nvdb",
    ] {
        let bytes = std::fs::read(data(file)).unwrap();
        for cut in (0..bytes.len()).filter(|c| *c < 400 || c % 211 == 0) {
            let e = io::nvdb::parse(&bytes[..cut], p).expect_err("a prefix must fail");
            assert!(e.to_string().contains("m.nvdb"), "{file} cut {cut}: {e}");
        }
        for m in mutants(&bytes, 0x9e37_79b9_7f4a_7c15u64, 1000) {
            let _ = io::nvdb::parse(&m, p);
        }
    }
    // The same without a checksum (all ones), so that damage reaches the tree walk.
    let mut bytes = std::fs::read(data("cloud_none.nvdb")).unwrap();
    bytes[GRID + 8..GRID + 16].fill(0xff);
    assert!(io::nvdb::parse(&bytes, p).is_ok());
    for m in mutants(&bytes, 0x2545_f491_4f6c_dd1du64, 1000) {
        let _ = io::nvdb::parse(&m, p);
    }
    // A child offset pointing back at its parent (a cycle) is refused, not walked forever.
    let mut b = bytes;
    let grid = GRID;
    let root = grid + 672 + 64;
    b[root + 64 + 8..root + 64 + 16].copy_from_slice(&(-(root as i64 - grid as i64)).to_le_bytes());
    let e = io::nvdb::parse(&b, p).unwrap_err().to_string();
    assert!(e.contains("grid.tree") && e.contains("does not fit"), "{e}");
}

/// A sparse file (`tests/data/make_sparse.sh`): two small spheres ≈ 1 680 voxels apart on each
/// axis and a tiled block, in a 1691³ box (4.8 G voxels — more than 2^32 — 19 GB dense). Read
/// as OpenVDB and as NanoVDB, it stays sparse — 38 MB, almost all of it the 4-byte-per-brick
/// index — and agrees with what libopenvdb reads: bounds, active voxel count, value sum, probes.
#[test]
fn a_sparse_file_stays_sparse_and_matches_libopenvdb() {
    let want: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("far_spheres.json")).unwrap()).unwrap();
    let lo: Vec<i64> = serde_json::from_value(want["lo"].clone()).unwrap();
    let hi: Vec<i64> = serde_json::from_value(want["hi"].clone()).unwrap();
    let res: Vec<usize> = (0..3).map(|a| (hi[a] - lo[a] + 1) as usize).collect();
    for name in ["far_spheres.vdb", "far_spheres.nvdb"] {
        let f = io::read_grid(data(name)).unwrap();
        assert_eq!(f.grid.res().to_vec(), res, "{name}");
        let b = f
            .grid
            .as_bricks()
            .expect("a .vdb/.nvdb grid is stored as bricks");
        // Index: 4 bytes per brick (212³ = 9.5 M bricks: 38.1 MB); pool: the leaves (a few
        // kB). (Another test in this binary sets a budget of 64 MiB.)
        assert!(
            f.grid.bytes() < 40_000_000,
            "{name}: {} bytes",
            f.grid.bytes()
        );
        let (stored, constant, _) = b.counts();
        // The spheres' leaves (≥ 2 each) stored; the 16³ block is 8 tiles.
        assert!(stored >= 4 && constant == 8, "{name}: {:?}", b.counts());
        let s = f.grid.stats();
        let n = res.iter().map(|&r| r as f64).product::<f64>();
        let active = want["active"].as_f64().unwrap();
        // Every active voxel is > 0 here, so non-zero voxels = active voxels.
        assert_eq!((s.nonzero_fraction * n).round(), active, "{name}");
        // Sum of f32 values accumulated in f64 in both: equal to 1e-9 relative.
        let sum = want["sum"].as_f64().unwrap();
        assert!(
            (s.mean * n / sum - 1.0).abs() < 1e-9,
            "{name}: {} vs {sum}",
            s.mean * n
        );
        for p in want["probes"].as_array().unwrap() {
            let p: Vec<f64> = serde_json::from_value(p.clone()).unwrap();
            let got = f.grid.get(p[0] as usize, p[1] as usize, p[2] as usize);
            // (compared as f32: the JSON holds the f32 value printed as a double)
            assert_eq!(got, p[3] as f32, "{name}: voxel {p:?}");
        }
        // The box's world bounds: (lo − ½, hi + ½) × 0.001.
        let (bmin, bmax) = f.bounds.unwrap();
        assert!((bmin.x - (lo[0] as f64 - 0.5) * 1e-3).abs() < 1e-9);
        assert!((bmax.z - (hi[2] as f64 + 0.5) * 1e-3).abs() < 1e-9);
    }
}
