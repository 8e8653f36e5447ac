//! The files of a data set on disk (layout in [`crate::data::dataset`]): `.npy` shards written
//! through a temporary and a rename (float32 or float16), SHA-256 checksums and the per-shard
//! checksum files that let a resume keep only intact shards, and the advisory lock on the
//! output folder.

use std::path::{Path, PathBuf};

use crate::data::datagen::DatagenError;

/// Columns of the `_meta.npy` arrays (`crate::data::dataset` names them), before any sky transfer.
pub const META_COLUMNS: usize = 15;

/// Writes `text` to `path` through a temporary beside it and a rename.
pub(crate) fn write_text(path: &Path, text: &str) -> Result<(), DatagenError> {
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text)
        .and_then(|_| std::fs::rename(&tmp, path))
        .map_err(|e| DatagenError::Set {
            what: path.display().to_string(),
            msg: e.to_string(),
        })
}

/// Hex SHA-256 of a file's bytes.
pub(crate) fn sha256_file(path: &Path) -> Result<String, DatagenError> {
    use sha2::{Digest, Sha256};
    use std::io::Read;
    let err = |e: std::io::Error| DatagenError::Set {
        what: path.display().to_string(),
        msg: e.to_string(),
    };
    let mut f = std::fs::File::open(path).map_err(err)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(err)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

pub(crate) fn write_npy(path: &Path, shape: &[u64], data: &[f32]) -> Result<(), DatagenError> {
    use npyz::WriterBuilder;
    let err = |e: std::io::Error| DatagenError::Set {
        what: path.display().to_string(),
        msg: e.to_string(),
    };
    let tmp = path.with_extension("npy.tmp");
    {
        let f = std::io::BufWriter::new(std::fs::File::create(&tmp).map_err(err)?);
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .writer(f)
            .begin_nd()
            .map_err(err)?;
        w.extend(data.iter().copied()).map_err(err)?;
        w.finish().map_err(err)?;
    }
    std::fs::rename(&tmp, path).map_err(err)
}

/// Like [`write_npy`], stored as float16.
pub(crate) fn write_npy_f16(path: &Path, shape: &[u64], data: &[f32]) -> Result<(), DatagenError> {
    use npyz::WriterBuilder;
    let err = |e: std::io::Error| DatagenError::Set {
        what: path.display().to_string(),
        msg: e.to_string(),
    };
    if let Some(i) = data
        .iter()
        .position(|v| v.abs() > f32::from(half::f16::MAX))
    {
        return Err(DatagenError::Set {
            what: path.display().to_string(),
            msg: format!(
                "value {i} is {}, beyond float16's range (65504); generate this set without --f16",
                data[i]
            ),
        });
    }
    let tmp = path.with_extension("npy.tmp");
    {
        let f = std::io::BufWriter::new(std::fs::File::create(&tmp).map_err(err)?);
        let mut w = npyz::WriteOptions::<half::f16>::new()
            .default_dtype()
            .shape(shape)
            .writer(f)
            .begin_nd()
            .map_err(err)?;
        w.extend(data.iter().map(|&v| half::f16::from_f32(v)))
            .map_err(err)?;
        w.finish().map_err(err)?;
    }
    std::fs::rename(&tmp, path).map_err(err)
}

pub(crate) fn rows_of(path: &Path) -> Option<u64> {
    let f = std::fs::File::open(path).ok()?;
    let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).ok()?;
    npy.shape().first().copied()
}

/// Reads a whole `.npy` array of f32.
pub(crate) fn read_f32(path: &Path) -> Result<Vec<f32>, String> {
    let f = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    npyz::NpyFile::new(std::io::BufReader::new(f))
        .and_then(|f| f.into_vec::<f32>())
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// Whether a finished shard can be kept on resume: `Ok(Some((sums, converged)))` when its files
/// are intact, `Ok(None)` when it is absent or unfinished, `Err(why)` when it is damaged. Its
/// checksums are those of its checksum file, else those the manifest lists (`listed`).
pub(crate) fn verify_shard(
    files: [&PathBuf; 3],
    sidecar: &Path,
    listed: Option<&[String; 3]>,
    n: u64,
) -> Result<Option<([String; 3], usize)>, String> {
    if files.iter().any(|f| !f.exists()) {
        return Ok(None);
    }
    let rows = files.map(|f| rows_of(f));
    if rows.iter().any(|r| *r != Some(n)) {
        return Err(format!(
            "{} rows in x, y and meta (expected {n} each)",
            rows.map(|r| r.map_or("unreadable".to_string(), |r| r.to_string()))
                .join(", ")
        ));
    }
    let sums: Vec<String> = files
        .iter()
        .map(|f| sha256_file(f).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let sums: [String; 3] = sums.try_into().expect("three files");
    let meta = || read_f32(files[2]);
    // Rows of META_COLUMNS, or more with the sky's transfer after them.
    let converged = |m: &[f32]| {
        let width = (m.len() / n.max(1) as usize).max(META_COLUMNS);
        m.chunks(width).filter(|r| r[11] > 0.5).count()
    };
    match std::fs::read_to_string(sidecar) {
        Ok(text) => {
            let want: Vec<&str> = text.split_whitespace().collect();
            for (i, f) in files.iter().enumerate() {
                if want.get(i) != Some(&sums[i].as_str()) {
                    return Err(format!(
                        "{} does not match its checksum in {}",
                        f.display(),
                        sidecar.display()
                    ));
                }
            }
            Ok(Some((sums.clone(), converged(&meta()?))))
        }
        Err(_) => {
            if let Some(want) = listed {
                for (i, f) in files.iter().enumerate() {
                    if want[i] != sums[i] {
                        return Err(format!(
                            "{} does not match its checksum in the manifest",
                            f.display()
                        ));
                    }
                }
            }
            // A shard of an older run: whole and finite, or recomputed.
            let m = meta()?;
            let y = read_f32(files[1])?;
            let x = read_f32(files[0])?;
            for (f, v) in [(files[0], &x), (files[1], &y), (files[2], &m)] {
                if let Some(i) = v.iter().position(|v| !v.is_finite()) {
                    return Err(format!("{}: value {i} is {}", f.display(), v[i]));
                }
            }
            write_sidecar(sidecar, &sums).map_err(|e| e.to_string())?;
            Ok(Some((sums, converged(&m))))
        }
    }
}

pub(crate) fn write_sidecar(path: &Path, sums: &[String; 3]) -> Result<(), DatagenError> {
    let tmp = path.with_extension("sha256.tmp");
    std::fs::write(&tmp, sums.join("\n") + "\n")
        .and_then(|_| std::fs::rename(&tmp, path))
        .map_err(|e| DatagenError::Set {
            what: path.display().to_string(),
            msg: e.to_string(),
        })
}

/// An advisory lock on `out/.lock` held for the whole run: a second concurrent writer to the
/// same folder is refused, naming the process that holds it (the lock is released when the
/// holder exits, even if it is killed).
pub(crate) fn lock_out(out: &Path) -> Result<std::fs::File, DatagenError> {
    use std::io::{Read, Seek, Write};
    let path = out.join(".lock");
    let err = |msg: String| DatagenError::Set {
        what: path.display().to_string(),
        msg,
    };
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| err(e.to_string()))?;
    match f.try_lock() {
        Ok(()) => {
            f.set_len(0).map_err(|e| err(e.to_string()))?;
            f.seek(std::io::SeekFrom::Start(0))
                .map_err(|e| err(e.to_string()))?;
            write!(f, "{}", std::process::id()).map_err(|e| err(e.to_string()))?;
            Ok(f)
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = f.read_to_string(&mut holder);
            Err(DatagenError::Set {
                what: out.display().to_string(),
                msg: format!(
                    "another datagen (process {}) is writing to this folder; wait for it or use another --out",
                    holder.trim()
                ),
            })
        }
        Err(std::fs::TryLockError::Error(e)) => Err(err(e.to_string())),
    }
}

/// Bytes one record takes on disk: its descriptor (float32, or float16), its label and its
/// metadata row (float32 each).
pub(crate) fn record_disk_bytes(f16: bool) -> u128 {
    let x = crate::descriptor::DESCRIPTOR_LEN * if f16 { 2 } else { 4 };
    (x + 4 + META_COLUMNS * 4) as u128
}

/// Free bytes on the file system that holds `path` (or its nearest existing ancestor, as the
/// folder may not exist yet); `None` where that cannot be asked.
fn free_bytes(path: &Path) -> Option<u128> {
    // A relative path's last ancestor is "", which is the current folder.
    let at = path
        .ancestors()
        .map(|p| {
            if p.as_os_str().is_empty() {
                Path::new(".")
            } else {
                p
            }
        })
        .find(|p| p.exists())?;
    #[cfg(unix)]
    {
        let s = rustix::fs::statvfs(at).ok()?;
        Some(s.f_bavail as u128 * s.f_frsize as u128)
    }
    #[cfg(not(unix))]
    {
        let _ = at;
        None
    }
}

/// Checks, before anything is written, that `records` more records fit on the file system of
/// `out`: the shards already in `out` (a resumed run) count as written. Asking for 10¹² records
/// is then a clear error at once instead of hours of work and a full disk.
pub(crate) fn check_disk(
    out: &Path,
    records: u128,
    what: &str,
    f16: bool,
) -> Result<(), DatagenError> {
    let Some(free) = free_bytes(out) else {
        return Ok(());
    };
    let held: u128 = std::fs::read_dir(out)
        .map(|dir| {
            dir.filter_map(|e| e.ok())
                .filter(|e| e.path().extension().is_some_and(|x| x == "npy"))
                .filter_map(|e| e.metadata().ok().map(|m| m.len() as u128))
                .sum()
        })
        .unwrap_or(0);
    let need = records.saturating_mul(record_disk_bytes(f16));
    if need.saturating_sub(held) > free {
        use nimbus_scene::memory::human;
        return Err(DatagenError::Set {
            what: out.display().to_string(),
            msg: format!(
                "fields `--records`, `--val-records`, `--test-records`: {records} records \
                 ({what}) need {} on disk ({} each; shards already here: {}), the file system \
                 has {} free",
                human(need),
                human(record_disk_bytes(f16)),
                human(held),
                human(free)
            ),
        });
    }
    Ok(())
}
