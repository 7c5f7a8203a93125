//! Files mjsafe reads and writes, with the rules every input and output follows:
//! - inputs are regular files (or FIFOs/stdin-like streams for logs, see [`open_input`]) read
//!   with a size limit, so `/dev/zero` or a multi-gigabyte file given by mistake is an error
//!   line, not an out-of-memory kill;
//! - outputs are written as `<final>.partial`, created exclusively (a second writer to the same
//!   path gets an error while the first holds it), and renamed over the final name only when
//!   complete; a final name that is a directory, a device or any other non-regular file, or an
//!   input of the same run, is refused before anything is written.

use std::fs::{File, OpenOptions};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Size limits of the inputs read whole into memory.
pub const SCENARIO_LIMIT: u64 = 16 << 20;
pub const MODEL_LIMIT: u64 = 64 << 20;
pub const SWEEP_FILE_LIMIT: u64 = 16 << 20;
pub const SUMMARY_LIMIT: u64 = 1 << 30;

#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{path}: cannot read {what}: {reason}")]
    Read {
        path: String,
        what: &'static str,
        reason: std::io::Error,
    },
    #[error("{path}: {what} is not a regular file ({kind})")]
    NotRegular {
        path: String,
        what: &'static str,
        kind: &'static str,
    },
    #[error("{path}: {what} is larger than the limit of {limit} ({size})")]
    TooLarge {
        path: String,
        what: &'static str,
        size: String,
        limit: String,
    },
    #[error("{path}: {what} is not valid UTF-8 text")]
    NotText { path: String, what: &'static str },
    #[error("{path}: cannot write {what}: {reason}")]
    Write {
        path: String,
        what: &'static str,
        reason: String,
    },
}

/// Bytes in a short human form: `512 B`, `16 MiB`, `1.5 GiB`.
pub fn human_bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = n as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 || value.fract() == 0.0 {
        format!("{value:.0} {}", UNITS[unit])
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// What kind of non-regular file a file type is, in words.
fn kind_of(file_type: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if file_type.is_dir() {
        "a directory"
    } else if file_type.is_char_device() {
        "a character device"
    } else if file_type.is_block_device() {
        "a block device"
    } else if file_type.is_fifo() {
        "a named pipe"
    } else if file_type.is_socket() {
        "a socket"
    } else if file_type.is_symlink() {
        "a symbolic link"
    } else if file_type.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

/// The error of a failed read of `path`.
fn read_error(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> FileError {
    let path = path.display().to_string();
    move |reason| FileError::Read { path, what, reason }
}

/// Checks that `path` is a regular file of at most `limit` bytes (following symlinks).
pub fn check_input(path: &Path, what: &'static str, limit: u64) -> Result<(), FileError> {
    let shown = path.display().to_string();
    let meta = std::fs::metadata(path).map_err(read_error(path, what))?;
    if !meta.is_file() {
        return Err(FileError::NotRegular {
            path: shown,
            what,
            kind: kind_of(meta.file_type()),
        });
    }
    if meta.len() > limit {
        return Err(FileError::TooLarge {
            path: shown,
            what,
            size: human_bytes(meta.len()),
            limit: human_bytes(limit),
        });
    }
    Ok(())
}

/// The bytes of a regular file of at most `limit` bytes. The limit also holds if the file
/// grows while it is read.
pub fn read_limited(path: &Path, what: &'static str, limit: u64) -> Result<Vec<u8>, FileError> {
    check_input(path, what, limit)?;
    let shown = path.display().to_string();
    let file = File::open(path).map_err(read_error(path, what))?;
    let mut bytes = Vec::new();
    file.take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(read_error(path, what))?;
    if bytes.len() as u64 > limit {
        return Err(FileError::TooLarge {
            path: shown,
            what,
            size: format!("more than {}", human_bytes(limit)),
            limit: human_bytes(limit),
        });
    }
    Ok(bytes)
}

/// [`read_limited`] as UTF-8 text.
pub fn read_text_limited(path: &Path, what: &'static str, limit: u64) -> Result<String, FileError> {
    let bytes = read_limited(path, what, limit)?;
    String::from_utf8(bytes).map_err(|_| FileError::NotText {
        path: path.display().to_string(),
        what,
    })
}

/// Opens an input that is streamed rather than read whole (a log): a regular file or a pipe,
/// never a directory or a device (reading `/dev/zero` would never end).
pub fn open_input(path: &Path, what: &'static str) -> Result<File, FileError> {
    use std::os::unix::fs::FileTypeExt;
    let shown = path.display().to_string();
    let meta = std::fs::metadata(path).map_err(read_error(path, what))?;
    let file_type = meta.file_type();
    if !(file_type.is_file() || file_type.is_fifo()) {
        return Err(FileError::NotRegular {
            path: shown,
            what,
            kind: kind_of(file_type),
        });
    }
    File::open(path).map_err(read_error(path, what))
}

/// The `.partial` files being written by this process, removed by [`remove_partials`] when
/// the process has to exit at once (a second Ctrl-C, a MuJoCo error). Files are created,
/// renamed and deleted under this lock, so none escapes the removal.
static PARTIALS: Registry = std::sync::Mutex::new(Partials {
    paths: Vec::new(),
    closed: false,
});

#[derive(Debug)]
struct Partials {
    paths: Vec<PathBuf>,
    /// Set by [`remove_partials`]: the process is exiting, no new output may start.
    closed: bool,
}

type Registry = std::sync::Mutex<Partials>;

/// The registry, even if a thread panicked while holding it (the list stays valid).
fn partials(registry: &Registry) -> std::sync::MutexGuard<'_, Partials> {
    registry.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn unregister(partials: &mut Partials, path: &Path) {
    if let Some(i) = partials.paths.iter().position(|p| p == path) {
        partials.paths.swap_remove(i);
    }
}

/// Removes every `.partial` file this process is writing (before an immediate exit) and
/// refuses every later [`OutputFile::create`]. Called from the Ctrl-C handler's thread (the
/// `ctrlc` crate runs it outside the signal context) and from MuJoCo's error callback, never
/// while the calling thread holds the lock, so waiting for it cannot deadlock.
pub fn remove_partials() {
    remove_all(&PARTIALS);
}

fn remove_all(registry: &Registry) {
    let mut partials = partials(registry);
    partials.closed = true;
    for path in partials.paths.drain(..) {
        let _ = std::fs::remove_file(path);
    }
}

/// Which existing regular files an output may replace.
#[derive(Debug, Clone, Copy)]
pub enum Replace {
    /// Any regular file (e.g. a summary inside mjsafe's own output directory).
    Any,
    /// Only files that start with these bytes (e.g. the MCAP magic): a scenario, a script or
    /// a document given by mistake as the output is kept.
    IfStartsWith(&'static [u8]),
}

/// An output being written: `<final>.partial`, exclusively ours while this value lives.
/// [`OutputFile::commit`] renames it to the final name; dropping it uncommitted deletes it.
#[derive(Debug)]
pub struct OutputFile {
    file: Option<File>,
    partial: PathBuf,
    target: PathBuf,
    what: &'static str,
    registry: &'static Registry,
}

/// `<path>.partial`.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut partial = path.as_os_str().to_owned();
    partial.push(".partial");
    PathBuf::from(partial)
}

/// Whether two paths name the same existing file (same device and inode).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// `path` with its directory resolved (symlinks, `..`) when that directory exists, for
/// comparing paths of files that may not exist yet.
fn normalised(path: &Path) -> PathBuf {
    let name = path.file_name();
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match (std::fs::canonicalize(dir), name) {
        (Ok(dir), Some(name)) => dir.join(name),
        _ => std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()),
    }
}

/// Whether two paths name the same file, existing or not: the same inode, or the same name
/// in the same (resolved) directory.
pub fn same_path(a: &Path, b: &Path) -> bool {
    same_file(a, b) || normalised(a) == normalised(b)
}

/// Whether the file at `path` can be read and starts with `magic`.
pub fn starts_with(path: &Path, magic: &[u8]) -> bool {
    let mut head = vec![0u8; magic.len()];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| head == magic)
}

/// Whether files can be created in directory `dir`: a probe file is created (exclusively) and
/// removed, so an output directory that cannot take the outputs is found before any work.
pub fn check_writable_dir(dir: &Path) -> Result<(), std::io::Error> {
    let probe = dir.join(format!(".mjsafe-write-probe-{}", std::process::id()));
    std::fs::OpenOptions::new().write(true).create_new(true).open(&probe)?;
    std::fs::remove_file(&probe)
}

/// Checks that `target` may be written as an output: it is not an input of the same run, and
/// it does not exist or is a regular file `replace` allows replacing. Nothing is created.
pub fn check_output(target: &Path, what: &'static str, replace: Replace, inputs: &[&Path]) -> Result<(), FileError> {
    let shown = target.display().to_string();
    let write_error = |reason: String| FileError::Write {
        path: shown.clone(),
        what,
        reason,
    };
    if target.as_os_str().is_empty() {
        return Err(write_error("the path is empty".into()));
    }
    {
        use std::os::unix::ffi::OsStrExt;
        if target.file_name().is_none() || target.as_os_str().as_bytes().ends_with(b"/") {
            return Err(write_error("it names a directory, expected a file name".into()));
        }
    }
    if let Some(input) = inputs.iter().find(|input| same_path(target, input)) {
        return Err(write_error(format!(
            "it is an input of this run ({}); choose another output path",
            input.display()
        )));
    }
    match std::fs::symlink_metadata(target) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(write_error(e.to_string())),
        Ok(meta) if !meta.file_type().is_file() => Err(write_error(format!(
            "it exists and is {}, which mjsafe never replaces",
            kind_of(meta.file_type())
        ))),
        Ok(_) => match replace {
            Replace::Any => Ok(()),
            Replace::IfStartsWith(magic) => {
                if starts_with(target, magic) {
                    Ok(())
                } else {
                    Err(write_error(format!(
                        "it exists and is not an mjsafe {what}; remove it or choose another path"
                    )))
                }
            }
        },
    }
}

impl OutputFile {
    /// Checks the target ([`check_output`]), creates its directory, and opens `<target>.partial`
    /// for writing, locked: if another process holds it, this is an error. A stale `.partial`
    /// (left by a killed process) is truncated and reused.
    pub fn create(
        target: &Path,
        what: &'static str,
        replace: Replace,
        inputs: &[&Path],
    ) -> Result<OutputFile, FileError> {
        Self::create_in(&PARTIALS, target, what, replace, inputs)
    }

    /// [`OutputFile::create`] registered in `registry`.
    fn create_in(
        registry: &'static Registry,
        target: &Path,
        what: &'static str,
        replace: Replace,
        inputs: &[&Path],
    ) -> Result<OutputFile, FileError> {
        check_output(target, what, replace, inputs)?;
        let shown = target.display().to_string();
        let write_error = |reason: String| FileError::Write {
            path: shown.clone(),
            what,
            reason,
        };
        if let Some(dir) = target.parent() {
            if !dir.as_os_str().is_empty() {
                std::fs::create_dir_all(dir).map_err(|e| write_error(format!("cannot create its directory: {e}")))?;
            }
        }
        let partial = partial_path(target);
        if let Ok(meta) = std::fs::symlink_metadata(&partial) {
            if !meta.file_type().is_file() {
                return Err(write_error(format!(
                    "{} exists and is {}",
                    partial.display(),
                    kind_of(meta.file_type())
                )));
            }
        }
        let cannot_create = |e: std::io::Error| write_error(format!("cannot create {}: {e}", partial.display()));
        // A new file is created and registered under the lock, so an exit in progress either
        // refuses it or removes it. A stale one is registered only once locked (it may be
        // another process's).
        let mut list = partials(registry);
        if list.closed {
            return Err(write_error("the process is exiting (interrupted)".into()));
        }
        let file = match OpenOptions::new().write(true).create_new(true).open(&partial) {
            Ok(file) => {
                list.paths.push(partial.clone());
                drop(list);
                if let Err(e) = lock(&file, &partial, &write_error) {
                    // Another process opened it first: it is theirs now.
                    unregister(&mut partials(registry), &partial);
                    return Err(e);
                }
                file
            }
            Err(e) if e.kind() != std::io::ErrorKind::AlreadyExists => return Err(cannot_create(e)),
            Err(_) => {
                drop(list);
                let file = OpenOptions::new().write(true).open(&partial).map_err(cannot_create)?;
                lock(&file, &partial, &write_error)?;
                let mut list = partials(registry);
                if list.closed {
                    let _ = std::fs::remove_file(&partial);
                    return Err(write_error("the process is exiting (interrupted)".into()));
                }
                list.paths.push(partial.clone());
                file
            }
        };
        // Registered: dropping `out` on an error deletes the file.
        let out = OutputFile {
            file: Some(file),
            partial,
            target: target.to_path_buf(),
            what,
            registry,
        };
        let file = out.file.as_ref().expect("just opened");
        file.set_len(0)
            .map_err(|e| write_error(format!("cannot truncate {}: {e}", out.partial.display())))?;
        Ok(out)
    }

    /// The open `.partial` file.
    pub fn file(&mut self) -> &mut File {
        self.file.as_mut().expect("the file is open until commit or drop")
    }

    /// A second handle to the `.partial` file (e.g. for a buffered writer that owns it); the
    /// lock stays with this value.
    pub fn try_clone_file(&self) -> Result<File, FileError> {
        self.file
            .as_ref()
            .expect("the file is open until commit or drop")
            .try_clone()
            .map_err(|e| self.error(format!("cannot duplicate the file handle: {e}")))
    }

    /// Writes all of `bytes` to the `.partial` file.
    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), FileError> {
        use std::io::Write;
        let result = self.file().write_all(bytes);
        result.map_err(|e| self.error(format!("cannot write {}: {e}", self.partial.display())))
    }

    pub fn partial_path(&self) -> &Path {
        &self.partial
    }

    pub fn target(&self) -> &Path {
        &self.target
    }

    /// An error about this output (named by its final path).
    pub fn error(&self, reason: String) -> FileError {
        FileError::Write {
            path: self.target.display().to_string(),
            what: self.what,
            reason,
        }
    }

    /// Flushes the file to disk and renames it to its final name (re-checking that the final
    /// name is still not a non-regular file). On an error the `.partial` file is deleted.
    pub fn commit(mut self) -> Result<PathBuf, FileError> {
        let file = self.file.as_ref().expect("the file is open until commit or drop");
        file.sync_all()
            .map_err(|e| self.error(format!("cannot flush {}: {e}", self.partial.display())))?;
        // Renamed under the lock: an exit in progress has removed it, or finds it renamed.
        let mut registry = partials(self.registry);
        if registry.closed {
            return Err(self.error("the process is exiting (interrupted)".into()));
        }
        if let Ok(meta) = std::fs::symlink_metadata(&self.target) {
            if !meta.file_type().is_file() {
                let kind = kind_of(meta.file_type());
                drop(registry);
                return Err(self.error(format!("it is now {kind}, which mjsafe never replaces")));
            }
        }
        let renamed = std::fs::rename(&self.partial, &self.target);
        if renamed.is_ok() {
            unregister(&mut registry, &self.partial);
            self.file = None;
        }
        drop(registry);
        renamed
            .map(|()| self.target.clone())
            .map_err(|e| self.error(format!("cannot move the finished file into place: {e}")))
    }
}

/// Locks an opened `.partial` file (`flock`); held by another process, this is an error.
fn lock(file: &File, partial: &Path, write_error: &dyn Fn(String) -> FileError) -> Result<(), FileError> {
    match file.try_lock() {
        Ok(()) => Ok(()),
        Err(std::fs::TryLockError::WouldBlock) => Err(write_error(format!(
            "another process is writing it ({} is locked)",
            partial.display()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(write_error(format!("cannot lock {}: {e}", partial.display()))),
    }
}

impl Drop for OutputFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            // Deleted before it leaves the list, so an exit in between still removes it.
            let mut registry = partials(self.registry);
            let _ = std::fs::remove_file(&self.partial);
            unregister(&mut registry, &self.partial);
        }
    }
}

/// Writes `bytes` to `target` through an [`OutputFile`] (whole, then renamed).
pub fn write_atomically(
    target: &Path,
    what: &'static str,
    replace: Replace,
    inputs: &[&Path],
    bytes: &[u8],
) -> Result<PathBuf, FileError> {
    let mut out = OutputFile::create(target, what, replace, inputs)?;
    out.write_all(bytes)?;
    out.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_large_files_are_refused_as_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_limited(Path::new("/dev/zero"), "scenario", 1024).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let e = read_limited(dir.path(), "scenario", 1024).unwrap_err();
        assert!(e.to_string().contains("a directory"), "{e}");
        let big = dir.path().join("big.toml");
        std::fs::write(&big, vec![b'#'; 2048]).unwrap();
        let e = read_limited(&big, "scenario", 1024).unwrap_err();
        assert!(e.to_string().contains("larger than the limit of 1 KiB (2 KiB)"), "{e}");
        assert_eq!(read_limited(&big, "scenario", 4096).unwrap().len(), 2048);
        assert!(open_input(Path::new("/dev/zero"), "log").is_err());
    }

    #[test]
    fn outputs_are_exclusive_renamed_when_committed_and_removed_when_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("sub/out.mcap");
        let mut first = OutputFile::create(&target, "log", Replace::Any, &[]).unwrap();
        let second = OutputFile::create(&target, "log", Replace::Any, &[]).unwrap_err();
        assert!(second.to_string().contains("another process is writing it"), "{second}");
        std::io::Write::write_all(first.file(), b"abc").unwrap();
        assert_eq!(first.commit().unwrap(), target);
        assert_eq!(std::fs::read(&target).unwrap(), b"abc");
        assert!(!partial_path(&target).exists());
        // Dropped uncommitted: the partial file is removed, the final file is untouched.
        let dropped = OutputFile::create(&target, "log", Replace::Any, &[]).unwrap();
        drop(dropped);
        assert!(!partial_path(&target).exists());
        assert_eq!(std::fs::read(&target).unwrap(), b"abc");
    }

    #[test]
    fn no_partial_file_survives_an_exit_in_progress() {
        let registry: &'static Registry = Box::leak(Box::new(Registry::new(Partials {
            paths: Vec::new(),
            closed: false,
        })));
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("r.mcap");
        let open = OutputFile::create_in(registry, &target, "log", Replace::Any, &[]).unwrap();
        // A stale partial of a killed process, not held by anyone.
        let stale = dir.path().join("s.mcap");
        std::fs::write(partial_path(&stale), b"old").unwrap();
        remove_all(registry);
        assert!(!partial_path(&target).exists(), "the open output is removed");
        // Created after the removal: refused, nothing created or left.
        let e = OutputFile::create_in(registry, &dir.path().join("late.mcap"), "log", Replace::Any, &[]).unwrap_err();
        assert!(e.to_string().contains("exiting"), "{e}");
        let e = OutputFile::create_in(registry, &stale, "log", Replace::Any, &[]).unwrap_err();
        assert!(e.to_string().contains("exiting"), "{e}");
        // Committed after the removal: an error, and no final file appears.
        let e = open.commit().unwrap_err();
        assert!(e.to_string().contains("exiting"), "{e}");
        let mut left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        left.sort();
        assert_eq!(left, ["s.mcap.partial"], "only the stale file, untouched");
    }

    #[test]
    fn non_regular_targets_inputs_and_foreign_files_are_never_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let e = OutputFile::create(Path::new("/dev/null"), "log", Replace::Any, &[]).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let e = OutputFile::create(dir.path(), "log", Replace::Any, &[]).unwrap_err();
        assert!(e.to_string().contains("a directory"), "{e}");
        let e = OutputFile::create(&dir.path().join("new/"), "log", Replace::Any, &[]).unwrap_err();
        assert!(e.to_string().contains("names a directory"), "{e}");
        let scenario = dir.path().join("s.toml");
        std::fs::write(&scenario, "name = 'x'").unwrap();
        let e = OutputFile::create(&scenario, "log", Replace::Any, &[&scenario]).unwrap_err();
        assert!(e.to_string().contains("is an input of this run"), "{e}");
        let e = OutputFile::create(&scenario, "MCAP log", Replace::IfStartsWith(b"\x89MCAP"), &[]).unwrap_err();
        assert!(e.to_string().contains("is not an mjsafe MCAP log"), "{e}");
        assert_eq!(std::fs::read_to_string(&scenario).unwrap(), "name = 'x'");
        let log = dir.path().join("old.mcap");
        std::fs::write(&log, b"\x89MCAP0\r\n").unwrap();
        write_atomically(
            &log,
            "MCAP log",
            Replace::IfStartsWith(b"\x89MCAP"),
            &[],
            b"\x89MCAP new",
        )
        .unwrap();
        assert_eq!(std::fs::read(&log).unwrap(), b"\x89MCAP new");
    }

    #[test]
    fn paths_compare_by_directory_and_name_even_before_they_exist() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        let a = dir.path().join("x.rrd");
        assert!(same_path(&a, &dir.path().join("sub/../x.rrd")));
        assert!(same_path(&a, &dir.path().join("./x.rrd")));
        assert!(!same_path(&a, &dir.path().join("sub/x.rrd")));
        std::fs::write(&a, "x").unwrap();
        std::os::unix::fs::symlink(&a, dir.path().join("link")).unwrap();
        assert!(same_path(&a, &dir.path().join("link")));
        let e = check_output(&dir.path().join("sub/../x.rrd"), "log", Replace::Any, &[&a]).unwrap_err();
        assert!(e.to_string().contains("is an input of this run"), "{e}");
    }

    #[test]
    fn human_sizes() {
        assert_eq!(human_bytes(512), "512 B");
        assert_eq!(human_bytes(16 << 20), "16 MiB");
        assert_eq!(human_bytes(3 << 29), "1.5 GiB");
    }
}
