//! The files of a data set on disk (layout in [`crate::data::dataset`]): `.npy` shards written
//! through a temporary and a rename (float32 or float16), SHA-256 checksums and the per-shard
//! checksum files that let a resume keep only intact shards, and the advisory lock on the
//! output folder.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use nimbus_scene::fsio::{self, FolderLock, Hold, LockError};

use crate::data::datagen::DatagenError;

/// Columns of the `_meta.npy` arrays (`crate::data::dataset` names them), before any sky transfer.
pub const META_COLUMNS: usize = 15;

/// Writes `text` to `path` whole or not at all ([`fsio::write_bytes`]).
pub(crate) fn write_text(path: &Path, text: &str) -> Result<(), DatagenError> {
    Ok(fsio::write_bytes(path, text.as_bytes())?)
}

/// Hex SHA-256 of a file's bytes (a regular file, streamed: at most the size it had when it was
/// opened).
pub(crate) fn sha256_file(path: &Path) -> Result<String, DatagenError> {
    use sha2::{Digest, Sha256};
    let (f, len) = fsio::open(path, Hold::Streamed)?;
    let mut f = f.take(len);
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f
            .read(&mut buf)
            .map_err(|e| nimbus_scene::Error::io(path, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Writes an `.npy` array of `T` (converted from f32 by `conv`) whole or not at all
/// ([`fsio::write_atomically`]: a hidden temporary beside `path`, renamed over it; what a full
/// disk or a killed run leaves is removed by the next write into the folder).
fn write_npy_as<T: npyz::AutoSerialize>(
    path: &Path,
    shape: &[u64],
    data: &[f32],
    conv: impl Fn(f32) -> T,
) -> Result<(), DatagenError> {
    use npyz::WriterBuilder;
    fsio::write_atomically(path, |tmp| {
        let io = |e: std::io::Error| nimbus_scene::Error::io(path, e);
        let mut f = std::io::BufWriter::new(fsio::create(tmp)?);
        {
            let mut w = npyz::WriteOptions::<T>::new()
                .default_dtype()
                .shape(shape)
                .writer(&mut f)
                .begin_nd()
                .map_err(io)?;
            w.extend(data.iter().map(|&v| conv(v))).map_err(io)?;
            w.finish().map_err(io)?;
        }
        f.flush().map_err(io)
    })?;
    Ok(())
}

pub(crate) fn write_npy(path: &Path, shape: &[u64], data: &[f32]) -> Result<(), DatagenError> {
    write_npy_as(path, shape, data, |v| v)
}

/// Like [`write_npy`], stored as float16.
pub(crate) fn write_npy_f16(path: &Path, shape: &[u64], data: &[f32]) -> Result<(), DatagenError> {
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
    write_npy_as(path, shape, data, half::f16::from_f32)
}

/// The row count in an `.npy` file's header: `Ok(None)` when the header is not one (a damaged
/// file); an error naming the file when it cannot be opened as a regular file.
pub(crate) fn rows_of(path: &Path) -> Result<Option<u64>, DatagenError> {
    let (f, _) = fsio::open(path, Hold::Streamed)?;
    Ok(npyz::NpyFile::new(std::io::BufReader::new(f))
        .ok()
        .and_then(|npy| npy.shape().first().copied()))
}

/// Why a shard cannot be kept: its folder holds something that is not a file datagen wrote
/// (refused), or its files are damaged (recomputed).
enum Bad {
    Refuse(DatagenError),
    Damaged(String),
}

impl From<DatagenError> for Bad {
    fn from(e: DatagenError) -> Self {
        Bad::Refuse(e)
    }
}

impl From<nimbus_scene::Error> for Bad {
    fn from(e: nimbus_scene::Error) -> Self {
        Bad::Refuse(e.into())
    }
}

/// Reads a whole `.npy` array of f32 (the decoded values, the file's size, held at once):
/// malformed contents are damage.
fn read_f32(path: &Path) -> Result<Vec<f32>, Bad> {
    let (f, _) = fsio::open(path, Hold::Times(1))?;
    npyz::NpyFile::new(std::io::BufReader::new(f))
        .and_then(|f| f.into_vec::<f32>())
        .map_err(|e| Bad::Damaged(format!("{}: {e}", path.display())))
}

/// Whether something (a file, a link, a pipe …) is at `path`: only a missing entry is absent.
pub(crate) fn present(path: &Path) -> bool {
    !matches!(std::fs::symlink_metadata(path), Err(e) if e.kind() == std::io::ErrorKind::NotFound)
}

/// Whether a finished shard can be kept on resume: `Ok(Ok(Some((sums, converged))))` when its
/// files are intact, `Ok(Ok(None))` when it is absent or unfinished, `Ok(Err(why))` when it is
/// damaged (to be recomputed). Its checksums are those of its checksum file, else those the
/// manifest lists (`listed`). Something at a shard's or checksum file's name that is not a
/// regular file (a pipe, a device, a folder, a dangling or looping link) or that is over the
/// memory budget is refused with an error naming it (`Err`): it is not a file datagen wrote,
/// and replacing it could destroy what it is.
#[allow(clippy::type_complexity)]
pub(crate) fn verify_shard(
    files: [&PathBuf; 3],
    sidecar: &Path,
    listed: Option<&[String; 3]>,
    n: u64,
) -> Result<Result<Option<([String; 3], usize)>, String>, DatagenError> {
    match verify(files, sidecar, listed, n) {
        Ok(kept) => Ok(Ok(kept)),
        Err(Bad::Damaged(why)) => Ok(Err(why)),
        Err(Bad::Refuse(e)) => Err(match e {
            DatagenError::Set { what, msg } => DatagenError::Set {
                what,
                msg: format!("{msg} (in a data-set folder; remove it or use another --out)"),
            },
            e => e,
        }),
    }
}

fn verify(
    files: [&PathBuf; 3],
    sidecar: &Path,
    listed: Option<&[String; 3]>,
    n: u64,
) -> Result<Option<([String; 3], usize)>, Bad> {
    // Whatever is there is opened and checked first, the checksum file too.
    let mut all_there = true;
    for f in files.iter().map(|f| f.as_path()).chain([sidecar]) {
        if present(f) {
            fsio::open(f, Hold::Streamed)?;
        } else if f != sidecar {
            all_there = false;
        }
    }
    if !all_there {
        return Ok(None);
    }
    let rows = files.map(|f| rows_of(f));
    let rows: Vec<Option<u64>> = rows.into_iter().collect::<Result<_, _>>()?;
    if rows.iter().any(|r| *r != Some(n)) {
        return Err(Bad::Damaged(format!(
            "{} rows in x, y and meta (expected {n} each)",
            rows.iter()
                .map(|r| r.map_or("unreadable".to_string(), |r| r.to_string()))
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let sums: Vec<String> = files
        .iter()
        .map(|f| sha256_file(f))
        .collect::<Result<_, _>>()?;
    let sums: [String; 3] = sums.try_into().expect("three files");
    let meta = || read_f32(files[2]);
    // Rows of META_COLUMNS, or more with the sky's transfer after them.
    let converged = |m: &[f32]| {
        let width = (m.len() / n.max(1) as usize).max(META_COLUMNS);
        m.chunks(width).filter(|r| r[11] > 0.5).count()
    };
    if present(sidecar) {
        // Bytes, not text: a damaged checksum file is a mismatch, not a refusal.
        let text = String::from_utf8_lossy(&fsio::read(sidecar)?).into_owned();
        let want: Vec<&str> = text.split_whitespace().collect();
        for (i, f) in files.iter().enumerate() {
            if want.get(i) != Some(&sums[i].as_str()) {
                return Err(Bad::Damaged(format!(
                    "{} does not match its checksum in {}",
                    f.display(),
                    sidecar.display()
                )));
            }
        }
        return Ok(Some((sums.clone(), converged(&meta()?))));
    }
    if let Some(want) = listed {
        for (i, f) in files.iter().enumerate() {
            if want[i] != sums[i] {
                return Err(Bad::Damaged(format!(
                    "{} does not match its checksum in the manifest",
                    f.display()
                )));
            }
        }
    }
    // A shard of an older run: whole and finite, or recomputed.
    let m = meta()?;
    let y = read_f32(files[1])?;
    let x = read_f32(files[0])?;
    for (f, v) in [(files[0], &x), (files[1], &y), (files[2], &m)] {
        if let Some(i) = v.iter().position(|v| !v.is_finite()) {
            return Err(Bad::Damaged(format!(
                "{}: value {i} is {}",
                f.display(),
                v[i]
            )));
        }
    }
    write_sidecar(sidecar, &sums)?;
    Ok(Some((sums, converged(&m))))
}

pub(crate) fn write_sidecar(path: &Path, sums: &[String; 3]) -> Result<(), DatagenError> {
    write_text(path, &(sums.join("\n") + "\n"))
}

/// An advisory lock on `out/.lock` held for the whole run ([`FolderLock`]): a second concurrent
/// writer to the same folder is refused, naming the process that holds it (the lock is released
/// when the holder exits, even if it is killed). A link at `.lock` is refused, never written
/// through; so is anything but a regular file.
pub(crate) fn lock_out(out: &Path) -> Result<FolderLock, DatagenError> {
    FolderLock::acquire(&out.join(".lock")).map_err(|e| match e {
        LockError::Held { holder, .. } => DatagenError::Set {
            what: out.display().to_string(),
            msg: format!(
                "another datagen (process {}) is writing to this folder; wait for it or use another --out",
                holder.as_deref().unwrap_or("unknown")
            ),
        },
        LockError::File(e) => e.into(),
    })
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
