//! One way to open a file for reading, one way to write one, one way to lock a folder.
//!
//! Every file Nimbus reads or writes goes through this module — main inputs (volumes, scenes,
//! images, models) and secondary ones alike (scripts, model cards, manifests, checksums, caches,
//! locks) — so each gets the same care:
//!
//! - **Reading** ([`open`], [`read`], [`read_to_string`]): the file is opened without blocking
//!   (`O_NONBLOCK`: opening a named pipe would wait for a writer that may never come) and checked
//!   on the opened descriptor (`fstat`): anything but a regular file (a pipe, a socket, a device
//!   such as `/dev/zero`, a folder) is refused at once. Its size times what the reader holds at
//!   once is checked against the memory budget ([`crate::memory`]) before a byte is read, and
//!   whole-file reads stop at the size `fstat` gave (a file that grows while it is read cannot
//!   make the read unbounded). Symbolic links are followed for reading; a loop or a dangling link
//!   is an error naming the path. Libraries that would open a path themselves (exr, npyz, image)
//!   get the opened, checked [`std::fs::File`].
//! - **Writing** ([`write_atomically`], [`write_bytes`]): a hidden temporary file in the same
//!   folder (created exclusively, never through a link), written, flushed to disk (`fsync`) and
//!   renamed over the target: a reader never sees a torn file and a full disk leaves the old file
//!   as it was. The temporary file is locked (`flock`) while it is written, so that a later run
//!   into the same folder can tell the leftovers of a dead run (lock free) from a live writer's
//!   (locked) and remove them ([`remove_dead_partials`]); pids are not used, as they are reused
//!   and folders are shared between machines.
//! - **Locks** ([`FolderLock`]): opened with `O_NOFOLLOW` (a symbolic link is refused, never
//!   written through), checked to be a regular file on the descriptor, held with `flock` (a killed
//!   holder frees it) and only then written.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// The marker in the names of temporary files being written ([`write_atomically`]).
pub const PARTIAL: &str = ".partial-";

/// How many bytes a reader holds per byte of the file, for the memory check of [`open`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// The file is streamed: nothing sized by the file is held (the reader checks what it
    /// allocates itself).
    Streamed,
    /// `n` times the file's size is held at once (the bytes, plus what is decoded from them).
    Times(u32),
}

/// Opens `path` for reading: a regular file (links followed), without waiting on a pipe, whose
/// size fits the budget as `hold` says. Returns the file and its size.
pub fn open(path: &Path, hold: Hold) -> Result<(File, u64)> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY);
    }
    let file = options.open(path).map_err(|e| io_error(path, e))?;
    let len = regular(&file, path, "a file to read")?;
    if let Hold::Times(n) = hold {
        crate::memory::check(
            len as u128 * n as u128,
            "file",
            &format!("reading this {} file", crate::memory::human(len as u128)),
        )
        .map_err(|e| e.at(path))?;
    }
    Ok((file, len))
}

/// Reads a whole file ([`open`] with the bytes held once): at most the size the file had when it
/// was opened.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    read_held(path, 1)
}

/// Reads a whole file whose bytes are held `times` over at once (the bytes, plus what is
/// decoded from them beside them): [`open`] with [`Hold::Times`], then as [`read`].
pub fn read_held(path: &Path, times: u32) -> Result<Vec<u8>> {
    let (file, len) = open(path, Hold::Times(times))?;
    read_opened(file, len, path)
}

/// Reads a whole file as UTF-8 text ([`read`]); other bytes are an error naming the file.
pub fn read_to_string(path: &Path) -> Result<String> {
    String::from_utf8(read(path)?).map_err(|e| {
        Error::parse(
            path,
            format!(
                "not UTF-8 text (byte {} is not valid UTF-8)",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Reads an optional file: `Ok(None)` when nothing is at `path` (no file, or a dangling link),
/// every other failure as [`read_to_string`].
pub fn read_to_string_if_exists(path: &Path) -> Result<Option<String>> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io_error(path, e)),
        Ok(_) => {}
    }
    match read_to_string(path) {
        // Gone since, or a link to nothing (said as a dangling link by `io_error`).
        Err(_)
            if std::fs::metadata(path).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound) =>
        {
            Ok(None)
        }
        other => other.map(Some),
    }
}

fn read_opened(file: File, len: u64, path: &Path) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(len as usize)
        .map_err(|_| Error::parse(path, "cannot allocate memory to read this file"))?;
    file.take(len)
        .read_to_end(&mut bytes)
        .map_err(|e| io_error(path, e))?;
    Ok(bytes)
}

/// The size of an opened file if it is a regular file; `what` says what was expected.
fn regular(file: &File, path: &Path, what: &str) -> Result<u64> {
    let meta = file.metadata().map_err(|e| io_error(path, e))?;
    if meta.is_file() {
        return Ok(meta.len());
    }
    let kind = if meta.is_dir() {
        "a folder"
    } else {
        "not a regular file (a pipe, socket or device)"
    };
    Err(Error::parse(path, format!("{kind}: expected {what}")))
}

/// An I/O error naming the path, with the cases users meet said in words.
fn io_error(path: &Path, e: std::io::Error) -> Error {
    #[cfg(unix)]
    if e.raw_os_error() == Some(libc::ELOOP) {
        return Error::parse(
            path,
            "a symbolic link that loops or that is not followed here (too many levels of links)",
        );
    }
    if e.kind() == std::io::ErrorKind::NotFound && std::fs::symlink_metadata(path).is_ok() {
        return Error::parse(path, "a symbolic link to nothing (dangling link)");
    }
    Error::io(path, e)
}

/// The hidden temporary beside `path` that [`write_atomically`] fills: `.NAME.partial-N.EXT`,
/// keeping the extension so that format choices by extension still work.
fn partial_path(path: &Path, n: u32) -> Result<PathBuf> {
    let name = path
        .file_name()
        .ok_or_else(|| Error::parse(path, "not a file path"))?
        .to_string_lossy();
    let tag = format!("{}-{n}", std::process::id());
    Ok(path.with_file_name(match path.extension() {
        Some(ext) => format!(".{name}{PARTIAL}{tag}.{}", ext.to_string_lossy()),
        None => format!(".{name}{PARTIAL}{tag}"),
    }))
}

/// Creates `path` exclusively (never through a link: `O_EXCL` refuses any existing name) and
/// takes its lock.
fn create_locked(path: &Path) -> std::io::Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true).write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o644);
    }
    let file = options.open(path)?;
    file.try_lock().map_err(|e| match e {
        std::fs::TryLockError::Error(e) => e,
        std::fs::TryLockError::WouldBlock => std::io::Error::other("locked by another process"),
    })?;
    Ok(file)
}

/// `true` when `file` is still the file at `path` (a cleaner did not remove it in between).
fn same_file(file: &File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::symlink_metadata(path)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        path.exists()
    }
}

/// Writes `path` whole or not at all: `write` fills a hidden temporary file beside it (same
/// extension), which is flushed to disk and renamed over `path`, then the folder is flushed. On
/// any failure (a full disk, a closed pipe, a bad path) the temporary file is removed and the
/// error names `path`. The temporary file stays locked while it is written; leftovers of dead
/// runs in the same folder are removed first ([`remove_dead_partials`]). A link at `path` is
/// replaced, never written through.
pub fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let dir = folder_of(path);
    remove_dead_partials(dir);
    let (tmp, lock) = (0..100)
        .find_map(|n| {
            let tmp = partial_path(path, n).ok()?;
            let f = create_locked(&tmp).ok()?;
            same_file(&f, &tmp).then_some((tmp, f))
        })
        .ok_or_else(|| {
            let e = create_locked(&partial_path(path, 100).unwrap_or_default())
                .err()
                .unwrap_or_else(|| std::io::Error::other("cannot create a temporary file"));
            Error::io(path, e)
        })?;
    // An error of `write` that names the temporary names `path`: the file the user asked for.
    let result = write(&tmp)
        .map_err(|e| renamed(e, &tmp, path))
        .and_then(|()| {
            File::open(&tmp)
                .and_then(|f| f.sync_all())
                .and_then(|()| std::fs::rename(&tmp, path))
                .map_err(|e| Error::io(path, e))
        });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    } else {
        sync_folder(dir);
    }
    drop(lock);
    result
}

/// `e`, naming `to` where it named `from`.
fn renamed(e: Error, from: &Path, to: &Path) -> Error {
    match e {
        Error::Io { path, err } if path == from => Error::io(to, err),
        Error::Invalid { path, field, msg } if path == from => Error::invalid(to, field, msg),
        Error::Parse { path, msg } if path == from => Error::parse(to, msg),
        e => e,
    }
}

/// Writes `bytes` to `path` atomically ([`write_atomically`]).
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |tmp| {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .truncate(true)
            .open(tmp)
            .map_err(|e| Error::io(path, e))?;
        f.write_all(bytes).map_err(|e| Error::io(path, e))
    })
}

/// Opens `path` for writing: created when missing, emptied when present, never through a link
/// (`O_NOFOLLOW`) and never waiting on a pipe; anything but a regular file is refused. For the
/// temporary file that [`write_atomically`] hands to its closure (a writer of our own that needs
/// a [`File`]); every other write goes through [`write_atomically`].
pub fn create(path: &Path) -> Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true).write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options
            .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_NOCTTY)
            .mode(0o644);
    }
    let file = options.open(path).map_err(|e| io_error(path, e))?;
    regular(&file, path, "a file to write")?;
    Ok(file)
}

fn folder_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Flushes a folder's entries (a rename) to disk; best effort (not every file system can).
fn sync_folder(dir: &Path) {
    #[cfg(unix)]
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    #[cfg(not(unix))]
    let _ = dir;
}

/// Removes the temporary files of dead writers in `dir`: every hidden `.NAME.partial-*` file
/// whose lock can be taken (a live writer holds its own; a killed one's lock was freed by the
/// system). Returns how many were removed. Links and other non-regular entries are left alone.
pub fn remove_dead_partials(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with('.') && name.contains(PARTIAL)) {
            continue;
        }
        let path = entry.path();
        let Ok(file) = open_no_follow(&path, false) else {
            continue;
        };
        if !file.metadata().is_ok_and(|m| m.is_file()) {
            continue;
        }
        if file.try_lock().is_ok() && same_file(&file, &path) && std::fs::remove_file(&path).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// Opens `path` without following a link at its last component and without waiting on a pipe;
/// `create` makes it when missing.
fn open_no_follow(path: &Path, create: bool) -> std::io::Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options
        .read(true)
        .write(true)
        .create(create)
        .truncate(false);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options
            .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_NOCTTY)
            .mode(0o644);
    }
    options.open(path)
}

/// An advisory lock on a file (`out/.lock`) held while this value lives: opened with
/// `O_NOFOLLOW` (a symbolic link there is refused and its target left untouched), checked to be
/// a regular file, held with `flock` (freed when the holder exits, even if killed), and only then
/// written with the holder's process id for the message of a refused second writer.
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
    path: PathBuf,
}

/// Why a [`FolderLock`] could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another process holds it; `holder` is what it wrote (its process id), if readable.
    #[error("{}: held by another process ({})", path.display(), holder.as_deref().unwrap_or("unknown"))]
    Held {
        path: PathBuf,
        holder: Option<String>,
    },
    /// The lock file could not be opened, is not a regular file, or is a link.
    #[error(transparent)]
    File(#[from] Error),
}

impl FolderLock {
    /// Takes the lock at `path`, creating the file when missing.
    pub fn acquire(path: &Path) -> Result<Self, LockError> {
        let file = open_no_follow(path, true).map_err(|e| {
            #[cfg(unix)]
            if e.raw_os_error() == Some(libc::ELOOP) {
                return Error::parse(
                    path,
                    "a symbolic link: a lock is never written through a link (remove it)",
                );
            }
            Error::io(path, e)
        })?;
        regular(&file, path, "a lock file")?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = (&file).take(64).read_to_string(&mut holder);
                let holder = Some(holder.trim().to_string()).filter(|h| !h.is_empty());
                return Err(LockError::Held {
                    path: path.to_path_buf(),
                    holder,
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(Error::io(path, e).into()),
        }
        let write = |mut f: &File| -> std::io::Result<()> {
            use std::io::Seek;
            f.set_len(0)?;
            f.seek(std::io::SeekFrom::Start(0))?;
            write!(f, "{}", std::process::id())
        };
        write(&file).map_err(|e| Error::io(path, e))?;
        Ok(Self {
            _file: file,
            path: path.to_path_buf(),
        })
    }

    /// The lock file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("nimbus-fsio-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn fifo(path: &Path) {
        let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    }

    #[test]
    fn reads_refuse_pipes_devices_folders_and_bad_links_at_once() {
        let d = dir("read");
        fifo(&d.join("pipe"));
        std::os::unix::fs::symlink(d.join("loop"), d.join("loop")).unwrap();
        std::os::unix::fs::symlink(d.join("none"), d.join("dangling")).unwrap();
        let cases: [(PathBuf, &str); 5] = [
            (d.join("pipe"), "pipe"),
            ("/dev/zero".into(), "device"),
            (d.clone(), "folder"),
            (d.join("loop"), "loops"),
            (d.join("dangling"), "dangling"),
        ];
        for (p, word) in cases {
            let t = std::time::Instant::now();
            let e = read(&p).unwrap_err().to_string();
            assert!(e.contains(&*p.to_string_lossy()) && e.contains(word), "{e}");
            // Opening a pipe blocks until a writer comes: any refusal is at once.
            assert!(t.elapsed().as_secs_f64() < 1.0, "{e}");
        }
        std::fs::write(d.join("ok"), "text").unwrap();
        assert_eq!(read_to_string(&d.join("ok")).unwrap(), "text");
        assert_eq!(read_to_string_if_exists(&d.join("none")).unwrap(), None);
        assert_eq!(read_to_string_if_exists(&d.join("dangling")).unwrap(), None);
        assert!(read_to_string_if_exists(&d.join("pipe")).is_err());
        std::fs::write(d.join("bin"), [0xff, 0xfe]).unwrap();
        let e = read_to_string(&d.join("bin")).unwrap_err().to_string();
        assert!(e.contains("UTF-8"), "{e}");
    }

    #[test]
    fn a_file_over_the_budget_is_refused_before_reading() {
        let d = dir("budget");
        let p = d.join("big");
        let f = File::create(&p).unwrap();
        // A sparse 1 TiB file: over any budget this test meets, and no disk used.
        f.set_len(1 << 40).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains("memory budget") && e.contains("big"), "{e}");
        // Streamed readers check their own allocations: opening is fine.
        assert_eq!(open(&p, Hold::Streamed).unwrap().1, 1 << 40);
    }

    #[test]
    fn writes_replace_links_and_leave_no_partials() {
        let d = dir("write");
        let victim = d.join("victim");
        std::fs::write(&victim, "keep").unwrap();
        let out = d.join("out.txt");
        std::os::unix::fs::symlink(&victim, &out).unwrap();
        write_bytes(&out, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "new");
        assert!(!std::fs::symlink_metadata(&out).unwrap().is_symlink());
        // A failed write leaves the old file and no temporary.
        let e = write_atomically(&out, |_| Err(Error::parse(&out, "disk full"))).unwrap_err();
        assert!(e.to_string().contains("disk full"));
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "new");
        let names: Vec<_> = std::fs::read_dir(&d).unwrap().flatten().collect();
        assert_eq!(names.len(), 2, "{names:?}");
    }

    #[test]
    fn dead_partials_go_live_ones_stay() {
        let d = dir("partials");
        let dead = d.join(".a.exr.partial-1-0.exr");
        std::fs::write(&dead, "torn").unwrap();
        let live = d.join(".b.exr.partial-2-0.exr");
        let held = create_locked(&live).unwrap();
        // A link with the marker is not followed and not removed.
        std::fs::write(d.join("target"), "t").unwrap();
        std::os::unix::fs::symlink(d.join("target"), d.join(".c.partial-3")).unwrap();
        write_bytes(&d.join("x.txt"), b"x").unwrap();
        assert!(!dead.exists());
        assert!(live.exists());
        assert!(std::fs::symlink_metadata(d.join(".c.partial-3")).is_ok());
        drop(held);
        assert_eq!(remove_dead_partials(&d), 1);
        assert!(!live.exists());
        assert_eq!(std::fs::read_to_string(d.join("target")).unwrap(), "t");
    }

    #[test]
    fn locks_refuse_links_and_second_holders() {
        let d = dir("lock");
        let victim = d.join("victim");
        std::fs::write(&victim, "precious").unwrap();
        let link = d.join(".lock");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        let e = FolderLock::acquire(&link).unwrap_err().to_string();
        assert!(e.contains("symbolic link") && e.contains(".lock"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
        std::fs::remove_file(&link).unwrap();
        fifo(&link);
        let e = FolderLock::acquire(&link).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        std::fs::remove_file(&link).unwrap();
        let held = FolderLock::acquire(&link).unwrap();
        assert_eq!(
            std::fs::read_to_string(&link).unwrap(),
            std::process::id().to_string()
        );
        match FolderLock::acquire(&link) {
            Err(LockError::Held { holder, .. }) => {
                assert_eq!(holder, Some(std::process::id().to_string()))
            }
            other => panic!("{other:?}"),
        }
        drop(held);
        FolderLock::acquire(&link).unwrap();
    }
}
