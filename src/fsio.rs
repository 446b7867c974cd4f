//! Files in and out, with the guarantees every command relies on.
//!
//! - **Reads are bounded**: [`read_text`] opens only regular files (a FIFO, a device such as
//!   `/dev/zero` or a folder is refused before a byte is read) and reads at most a stated number
//!   of bytes.
//! - **Writes are atomic**: [`write_atomic`] writes a temporary sibling and renames it over the
//!   target, so a reader never sees half a file.
//! - **Outputs appear whole or not at all**: a command stages its output ([`Staged`]) in a hidden
//!   temporary sibling of the target (`.NAME.aift-tmp-PID`), under an exclusive lock
//!   (`.NAME.aift-lock`) that a second writer of the same target finds taken (it fails at once
//!   with [`FsError::Busy`]). [`Staged::commit`] swaps the staged folder into place in one atomic
//!   step (`renameat2(RENAME_EXCHANGE)` on Linux), so a kill at any moment leaves either no
//!   folder, the complete old one or the complete new one. A staging folder left by a killed
//!   process is hidden and is removed by the next command that writes the same target.
//!
//! This module sits below every stage: it knows nothing of scenarios or reports.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Largest scenario or campaign file read (bytes).
pub const MAX_SCENARIO_BYTES: u64 = 1 << 20;
/// Largest URDF file read (bytes).
pub const MAX_URDF_BYTES: u64 = 32 << 20;
/// Largest GP model file read (bytes).
pub const MAX_GP_BYTES: u64 = 64 << 20;
/// Largest detector calibration file read (bytes).
pub const MAX_CALIBRATION_BYTES: u64 = 1 << 30;
/// Largest trajectory file read back (bytes).
pub const MAX_TRAJECTORY_BYTES: u64 = 8 << 30;

/// The marker file every output folder of aift carries: `--force` replaces only folders that
/// have it (or are empty), never a folder of the user's.
pub const OUTPUT_MARKER: &str = ".aift-output";

/// A digest of this build's source (`build.rs`: the files under `src/`, `Cargo.toml`,
/// `Cargo.lock`). Campaign journals and cached calibrations carry it: work of another build is
/// never resumed or reused, though the crate's version stays the same between commits.
pub const SOURCE_DIGEST: &str = env!("AIFT_SOURCE_DIGEST");

/// Errors of reading inputs and writing outputs, each naming the path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FsError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a regular file ({kind}); only regular files are read")]
    NotRegular { path: PathBuf, kind: &'static str },
    #[error("{path}: {size} bytes; at most {limit} bytes are read from such a file")]
    TooLarge {
        path: PathBuf,
        size: u64,
        limit: u64,
    },
    #[error("{path}: not UTF-8 text")]
    NotText { path: PathBuf },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: another process is writing this output (its lock {lock} is held)")]
    Busy { path: PathBuf, lock: PathBuf },
    #[error("{path}: {message}")]
    BadOutput { path: PathBuf, message: String },
}

impl FsError {
    /// The path the error is about.
    pub fn path(&self) -> &Path {
        match self {
            Self::Read { path, .. }
            | Self::NotRegular { path, .. }
            | Self::TooLarge { path, .. }
            | Self::NotText { path }
            | Self::Write { path, .. }
            | Self::Busy { path, .. }
            | Self::BadOutput { path, .. } => path,
        }
    }

    /// Whether the input (a path given by the user) is at fault, as opposed to the machine.
    pub fn is_input_error(&self) -> bool {
        !matches!(self, Self::Write { .. })
    }
}

fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if meta.file_type().is_symlink() {
        return "a symbolic link";
    }
    if meta.is_dir() {
        "a folder"
    } else if meta.is_file() {
        "a file"
    } else {
        "not a file"
    }
}

/// Opens a regular file of at most `limit` bytes for streaming reads (a FIFO or device is
/// refused before it is opened; reads stop one byte past the limit, so a file that grows is
/// caught by the caller).
pub fn open_bounded(
    path: &Path,
    limit: u64,
) -> Result<(std::io::Take<std::fs::File>, u64), FsError> {
    let read_err = |source| FsError::Read {
        path: path.to_path_buf(),
        source,
    };
    // Checked before opening: opening a FIFO for reading blocks until a writer appears.
    let meta = std::fs::metadata(path).map_err(read_err)?;
    if !meta.is_file() {
        return Err(FsError::NotRegular {
            path: path.to_path_buf(),
            kind: kind_of(&meta),
        });
    }
    let mut options = OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // A file swapped for a FIFO between the check and the open must not block either.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(read_err)?;
    let meta = file.metadata().map_err(read_err)?;
    if !meta.is_file() {
        return Err(FsError::NotRegular {
            path: path.to_path_buf(),
            kind: kind_of(&meta),
        });
    }
    if meta.len() > limit {
        return Err(FsError::TooLarge {
            path: path.to_path_buf(),
            size: meta.len(),
            limit,
        });
    }
    let len = meta.len();
    Ok((file.take(limit + 1), len))
}

/// Reads at most `limit` bytes of a regular file.
pub fn read_bounded(path: &Path, limit: u64) -> Result<Vec<u8>, FsError> {
    let read_err = |source| FsError::Read {
        path: path.to_path_buf(),
        source,
    };
    let (mut file, len) = open_bounded(path, limit)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.read_to_end(&mut bytes).map_err(read_err)?;
    if bytes.len() as u64 > limit {
        return Err(FsError::TooLarge {
            path: path.to_path_buf(),
            size: bytes.len() as u64,
            limit,
        });
    }
    Ok(bytes)
}

/// Reads a regular file of at most `limit` bytes as UTF-8 text.
pub fn read_text(path: &Path, limit: u64) -> Result<String, FsError> {
    String::from_utf8(read_bounded(path, limit)?).map_err(|_| FsError::NotText {
        path: path.to_path_buf(),
    })
}

/// An existing file output must be a regular file: outputs are moved into place by a rename,
/// which would replace a device, a FIFO, a socket or a symbolic link (as root, `--out /dev/null`
/// would leave /dev/null an empty regular file). Such targets are refused, not streamed to.
fn check_file_output(target: &Path) -> Result<(), FsError> {
    match std::fs::symlink_metadata(target) {
        Ok(meta) if meta.is_file() => Ok(()),
        Ok(meta) if meta.is_dir() => Err(FsError::BadOutput {
            path: target.to_path_buf(),
            message: "is a folder; a file is expected".into(),
        }),
        Ok(meta) => Err(FsError::BadOutput {
            path: target.to_path_buf(),
            message: format!(
                "is {}; aift writes an output whole and moves it into place with a rename, \
                 which would replace it: give a regular file or a new path",
                kind_of(&meta)
            ),
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(FsError::BadOutput {
            path: target.to_path_buf(),
            message: format!("cannot inspect it: {e}"),
        }),
    }
}

/// Writes `bytes` to `path` atomically (temporary file in the same folder, then rename); an
/// existing `path` must be a regular file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FsError> {
    check_file_output(path)?;
    let err = |source| FsError::Write {
        path: path.to_path_buf(),
        source,
    };
    let tmp = temp_sibling(path, "tmp");
    let result = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(err)
}

/// The folder a path lives in (`.` for a bare name).
fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn file_name_of(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into())
}

/// A hidden sibling `.NAME.aift-<what>-PID`.
fn temp_sibling(path: &Path, what: &str) -> PathBuf {
    parent_of(path).join(format!(
        ".{}.aift-{what}-{}",
        file_name_of(path),
        std::process::id()
    ))
}

/// An exclusive lock on an output target, held while it is staged.
#[derive(Debug)]
struct OutputLock {
    path: PathBuf,
    file: Option<File>,
}

impl OutputLock {
    /// Takes the lock of `target` or fails at once if another process holds it.
    fn acquire(target: &Path) -> Result<Self, FsError> {
        let path = parent_of(target).join(format!(".{}.aift-lock", file_name_of(target)));
        // The lock file is removed when released; a racing process may have opened the old
        // file, so after locking check that the path still names the file locked.
        for _ in 0..16 {
            let file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| FsError::BadOutput {
                    path: target.to_path_buf(),
                    message: format!("cannot create its lock file {}: {e}", path.display()),
                })?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    return Err(FsError::Busy {
                        path: target.to_path_buf(),
                        lock: path,
                    });
                }
                Err(std::fs::TryLockError::Error(e)) => {
                    return Err(FsError::BadOutput {
                        path: target.to_path_buf(),
                        message: format!("cannot lock {}: {e}", path.display()),
                    });
                }
            }
            if same_file(&file, &path) {
                return Ok(Self {
                    path,
                    file: Some(file),
                });
            }
        }
        Err(FsError::Busy {
            path: target.to_path_buf(),
            lock: path,
        })
    }
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_: &File, path: &Path) -> bool {
    path.exists()
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, then released.
        let _ = std::fs::remove_file(&self.path);
        self.file.take();
    }
}

/// What is being staged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A folder of files.
    Folder,
    /// A single file.
    File,
}

/// An output being written: a hidden temporary sibling of the target, locked, that
/// [`Staged::commit`] moves into place atomically. Dropped without a commit, it is removed.
#[derive(Debug)]
pub struct Staged {
    target: PathBuf,
    temp: PathBuf,
    kind: OutputKind,
    committed: bool,
    _lock: OutputLock,
}

impl Staged {
    /// Prepares to write `target`. Checked here, before any work: the folder it goes in can be
    /// created and written; a folder target that exists is a folder, and is empty, or (with
    /// `force`) an earlier aift output; a file target is not a folder; no other process is
    /// writing it. Stale staging left by a killed process is removed.
    pub fn begin(target: &Path, kind: OutputKind, force: bool) -> Result<Self, FsError> {
        let bad = |message: String| FsError::BadOutput {
            path: target.to_path_buf(),
            message,
        };
        let name = target
            .file_name()
            .ok_or_else(|| bad("names no file or folder (it ends in `..` or `/`)".into()))?;
        if name.to_string_lossy().starts_with('.') && name.to_string_lossy().contains(".aift-") {
            return Err(bad("is a name aift uses for its own staging".into()));
        }
        // Devices, FIFOs, sockets and links are refused before anything is created beside them.
        match kind {
            OutputKind::File => {
                if target.as_os_str().as_encoded_bytes().ends_with(b"/") {
                    return Err(bad("ends in `/`; a file is expected".into()));
                }
                check_file_output(target)?
            }
            OutputKind::Folder => {
                if let Ok(meta) = std::fs::symlink_metadata(target)
                    && !meta.is_dir()
                {
                    return Err(bad(format!(
                        "exists and is {}, not a folder",
                        kind_of(&meta)
                    )));
                }
            }
        }
        let parent = parent_of(target);
        if let Ok(meta) = std::fs::metadata(&parent)
            && !meta.is_dir()
        {
            return Err(bad(format!("{} is not a folder", parent.display())));
        }
        std::fs::create_dir_all(&parent)
            .map_err(|e| bad(format!("cannot create {}: {e}", parent.display())))?;
        let lock = OutputLock::acquire(target)?;
        match std::fs::symlink_metadata(target) {
            Ok(meta) => match kind {
                OutputKind::Folder => {
                    if !meta.is_dir() {
                        return Err(bad("exists and is not a folder".into()));
                    }
                    let mut entries = std::fs::read_dir(target)
                        .map_err(|e| bad(format!("cannot list it: {e}")))?;
                    let empty = entries.next().is_none();
                    if !empty {
                        if !force {
                            return Err(bad(
                                "exists and is not empty; pass --force to replace it".into()
                            ));
                        }
                        if !target.join(OUTPUT_MARKER).is_file() {
                            return Err(bad(format!(
                                "is not a folder aift wrote (no {OUTPUT_MARKER} in it); \
                                 --force replaces only aift's own outputs"
                            )));
                        }
                    }
                }
                OutputKind::File => check_file_output(target)?,
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(bad(format!("cannot inspect it: {e}"))),
        }
        remove_stale_staging(target);
        let temp = temp_sibling(target, "tmp");
        let created = match kind {
            OutputKind::Folder => std::fs::create_dir(&temp),
            OutputKind::File => File::create(&temp).map(|_| ()),
        };
        // A full disk is the machine's fault (exit 1), a folder the user cannot write theirs.
        let staging_error = |e: std::io::Error| {
            if machine_fault(&e) {
                FsError::Write {
                    path: target.to_path_buf(),
                    source: e,
                }
            } else {
                bad(format!("cannot write in {}: {e}", parent.display()))
            }
        };
        created.map_err(staging_error)?;
        if kind == OutputKind::Folder {
            std::fs::write(temp.join(OUTPUT_MARKER), b"aift output folder\n").map_err(|e| {
                let _ = std::fs::remove_dir_all(&temp);
                staging_error(e)
            })?;
        }
        Ok(Self {
            target: target.to_path_buf(),
            temp,
            kind,
            committed: false,
            _lock: lock,
        })
    }

    /// Where to write: the staging folder, or the staging file.
    pub fn path(&self) -> &Path {
        &self.temp
    }

    /// The final target.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Writes `bytes` as the staged file and moves it into place (a file output written in
    /// one piece); a write error names the target.
    pub fn commit_bytes(self, bytes: &[u8]) -> Result<(), FsError> {
        debug_assert_eq!(
            self.kind,
            OutputKind::File,
            "commit_bytes is for file outputs"
        );
        std::fs::write(&self.temp, bytes).map_err(|source| FsError::Write {
            path: self.target.clone(),
            source,
        })?;
        self.commit()
    }

    /// Moves the staged output into place in one atomic step.
    pub fn commit(mut self) -> Result<(), FsError> {
        let err = |source| FsError::Write {
            path: self.target.clone(),
            source,
        };
        sync_tree(&self.temp).map_err(err)?;
        match self.kind {
            OutputKind::File => std::fs::rename(&self.temp, &self.target).map_err(err)?,
            OutputKind::Folder => {
                if std::fs::symlink_metadata(&self.target).is_ok() {
                    exchange(&self.temp, &self.target).map_err(err)?;
                    // The temporary path now holds the old folder.
                    let _ = std::fs::remove_dir_all(&self.temp);
                } else {
                    std::fs::rename(&self.temp, &self.target).map_err(err)?;
                }
            }
        }
        if let Ok(dir) = File::open(parent_of(&self.target)) {
            let _ = dir.sync_all();
        }
        self.committed = true;
        Ok(())
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            let _ = match self.kind {
                OutputKind::Folder => std::fs::remove_dir_all(&self.temp),
                OutputKind::File => std::fs::remove_file(&self.temp),
            };
        }
    }
}

/// Errors of the machine rather than of the path given: a full disk, an exceeded quota, an I/O
/// error.
fn machine_fault(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
    ) || e.raw_os_error() == Some(libc::EIO)
}

/// Flushes every file of a staged output to disk before it is moved into place.
fn sync_tree(path: &Path) -> std::io::Result<()> {
    let meta = std::fs::symlink_metadata(path)?;
    if meta.is_dir() {
        for entry in std::fs::read_dir(path)? {
            sync_tree(&entry?.path())?;
        }
        File::open(path)?.sync_all()
    } else if meta.is_file() {
        OpenOptions::new().write(true).open(path)?.sync_all()
    } else {
        Ok(())
    }
}

/// Removes hidden staging siblings of `target` left by killed processes (the caller holds the
/// target's lock, so no live process is writing them).
fn remove_stale_staging(target: &Path) {
    let prefix = format!(".{}.aift-tmp-", file_name_of(target));
    let Ok(entries) = std::fs::read_dir(parent_of(target)) else {
        return;
    };
    for entry in entries.flatten() {
        if entry.file_name().to_string_lossy().starts_with(&prefix) {
            let path = entry.path();
            let _ = if path.is_dir() {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
        }
    }
}

/// Swaps two paths atomically (Linux `renameat2(RENAME_EXCHANGE)`); elsewhere, or on a file
/// system without it, two renames (a kill between them leaves the old folder at `a`).
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use std::ffi::CString;
        use std::os::unix::ffi::OsStrExt;
        let ca = CString::new(a.as_os_str().as_bytes())?;
        let cb = CString::new(b.as_os_str().as_bytes())?;
        // SAFETY: two valid NUL-terminated paths; the syscall reads them and nothing else.
        let rc = unsafe {
            libc::syscall(
                libc::SYS_renameat2,
                libc::AT_FDCWD,
                ca.as_ptr(),
                libc::AT_FDCWD,
                cb.as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        if rc == 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if !matches!(e.raw_os_error(), Some(libc::EINVAL) | Some(libc::ENOSYS)) {
            return Err(e);
        }
    }
    let old = temp_sibling(b, "old");
    std::fs::rename(b, &old)?;
    std::fs::rename(a, b)?;
    std::fs::rename(&old, a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_appears_only_on_commit_and_replaces_the_old_one_whole() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        let s = Staged::begin(&target, OutputKind::Folder, false).unwrap();
        std::fs::write(s.path().join("a.txt"), "new").unwrap();
        assert!(!target.exists());
        s.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(target.join("a.txt")).unwrap(),
            "new"
        );
        // Not empty: needs force; with force the old file b.txt does not survive.
        std::fs::write(target.join("b.txt"), "stale").unwrap();
        assert!(Staged::begin(&target, OutputKind::Folder, false).is_err());
        let s = Staged::begin(&target, OutputKind::Folder, true).unwrap();
        std::fs::write(s.path().join("a.txt"), "newer").unwrap();
        s.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(target.join("a.txt")).unwrap(),
            "newer"
        );
        assert!(!target.join("b.txt").exists());
        // Nothing staged is left beside it.
        let names: Vec<String> = std::fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec!["out".to_string()]);
    }

    #[test]
    fn dropped_without_commit_leaves_nothing_and_a_second_writer_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        let s = Staged::begin(&target, OutputKind::Folder, false).unwrap();
        let second = Staged::begin(&target, OutputKind::Folder, false).unwrap_err();
        assert!(matches!(second, FsError::Busy { .. }), "{second}");
        drop(s);
        assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
    }

    #[test]
    fn force_refuses_a_folder_aift_did_not_write() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("mine");
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("thesis.tex"), "precious").unwrap();
        let e = Staged::begin(&target, OutputKind::Folder, true).unwrap_err();
        assert!(e.to_string().contains("not a folder aift wrote"), "{e}");
        assert!(target.join("thesis.tex").exists());
    }

    #[test]
    fn reads_refuse_devices_fifos_folders_and_oversized_files() {
        let tmp = tempfile::tempdir().unwrap();
        assert!(matches!(
            read_text(Path::new("/dev/zero"), 100),
            Err(FsError::NotRegular { .. })
        ));
        assert!(matches!(
            read_text(tmp.path(), 100),
            Err(FsError::NotRegular { .. })
        ));
        let fifo = tmp.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_string_lossy().as_bytes()).unwrap();
        // SAFETY: a valid path; creates a FIFO in the temporary folder.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(matches!(
            read_text(&fifo, 100),
            Err(FsError::NotRegular { .. })
        ));
        let big = tmp.path().join("big");
        std::fs::write(&big, vec![b'a'; 101]).unwrap();
        assert!(matches!(
            read_text(&big, 100),
            Err(FsError::TooLarge { .. })
        ));
        std::fs::write(&big, vec![b'a'; 100]).unwrap();
        assert_eq!(read_text(&big, 100).unwrap().len(), 100);
    }
}
