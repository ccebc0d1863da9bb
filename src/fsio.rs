//! File output that is never half-written: [`write_atomically`], the crate's one way
//! to write a file that readers may see, and [`create_parent_dir`] for files in new
//! directories; [`TempDir`], a temporary directory that removes itself.
//!
//! [`FileError`] is the crate's one shape of a failed file operation (what was being
//! done, the path and the operating system's error); every module's error enum holds
//! it in one variant. [`read`], [`read_to_string`], [`write`] (atomically) and
//! [`create_dir_all`] return it, so callers write no `map_err` of their own.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// What was being done to a file when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileOp {
    /// Reading it (or opening it to read).
    Read,
    /// Writing it.
    Write,
    /// Creating a directory (and its parents).
    CreateDir,
    /// Listing a directory.
    ListDir,
    /// Removing a file or directory.
    Remove,
}

impl std::fmt::Display for FileOp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FileOp::Read => "read",
            FileOp::Write => "write",
            FileOp::CreateDir => "create directory",
            FileOp::ListDir => "list directory",
            FileOp::Remove => "remove",
        })
    }
}

/// A file operation that failed: "cannot read mug.obj: No such file or directory (os
/// error 2)".
#[derive(Debug, thiserror::Error)]
#[error("cannot {op} {}: {source}", path.display())]
pub struct FileError {
    /// What was being done.
    pub op: FileOp,
    /// The file or directory.
    pub path: PathBuf,
    /// The operating system's error.
    #[source]
    pub source: std::io::Error,
}

impl FileError {
    /// `op` on `path` failed with `source`.
    pub fn new(op: FileOp, path: &Path, source: std::io::Error) -> FileError {
        FileError {
            op,
            path: path.to_path_buf(),
            source,
        }
    }

    /// For `map_err`: the error of `op` on `path`.
    pub fn of(op: FileOp, path: &Path) -> impl FnOnce(std::io::Error) -> FileError + '_ {
        move |source| FileError::new(op, path, source)
    }
}

/// The bytes of the file `path`.
pub fn read(path: &Path) -> Result<Vec<u8>, FileError> {
    std::fs::read(path).map_err(FileError::of(FileOp::Read, path))
}

/// The text of the file `path` (UTF-8).
pub fn read_to_string(path: &Path) -> Result<String, FileError> {
    std::fs::read_to_string(path).map_err(FileError::of(FileOp::Read, path))
}

/// The file `path`, opened to read.
pub fn open(path: &Path) -> Result<std::fs::File, FileError> {
    std::fs::File::open(path).map_err(FileError::of(FileOp::Read, path))
}

/// [`write_atomically`], naming the file in its error.
pub fn write(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    write_atomically(path, bytes).map_err(FileError::of(FileOp::Write, path))
}

/// Creates the directory `path` and its parents.
pub fn create_dir_all(path: &Path) -> Result<(), FileError> {
    std::fs::create_dir_all(path).map_err(FileError::of(FileOp::CreateDir, path))
}

/// Writes `bytes` to `path` so that readers see the old file or the whole new one,
/// never part of it: a temporary file in the same directory is written, synced and
/// renamed over `path` (and removed if anything fails).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "path names no file")
    })?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Creates the directory `path` goes into (and its parents), if `path` names one.
pub fn create_parent_dir(path: &Path) -> std::io::Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => std::fs::create_dir_all(dir),
        _ => Ok(()),
    }
}

/// A fresh directory under the system's temporary directory
/// (`graspcell-<tag>-<pid>-<n>`), removed with everything in it when dropped, also
/// when the thread unwinds from a panic: scratch space for a command (`cell demo`
/// without `--run-dir`, a benchmark) and the one temporary directory of the unit and
/// integration tests. It derefs to its [`Path`].
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    /// Creates an empty directory named after `tag`.
    pub fn new(tag: &str) -> std::io::Result<TempDir> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!(
            "graspcell-{tag}-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        Ok(TempDir(dir))
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for TempDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = TempDir::new("fsio-atomic").unwrap();
        let path = dir.join("sub").join("f.txt");
        create_parent_dir(&path).unwrap();
        write_atomically(&path, b"one").unwrap();
        write_atomically(&path, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "two");
        let names: Vec<_> = std::fs::read_dir(path.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1);
        assert!(write_atomically(&dir.join("missing/f.txt"), b"x").is_err());
        create_parent_dir(Path::new("f.txt")).unwrap();
    }

    #[test]
    fn a_file_error_names_the_operation_and_the_path() {
        let dir = TempDir::new("fsio-error").unwrap();
        let missing = dir.join("missing.json");
        let err = read_to_string(&missing).unwrap_err();
        assert_eq!(err.op, FileOp::Read);
        let text = err.to_string();
        assert!(text.starts_with("cannot read "), "{text}");
        assert!(
            text.contains("missing.json") && text.contains("os error 2"),
            "{text}"
        );
        let err = write(&dir.join("no/such/dir/f"), b"x").unwrap_err();
        assert!(err.to_string().starts_with("cannot write "), "{err}");
        write(&dir.join("f"), b"x").unwrap();
        assert_eq!(read(&dir.join("f")).unwrap(), b"x");
        let err = create_dir_all(&dir.join("f").join("d")).unwrap_err();
        assert!(
            err.to_string().starts_with("cannot create directory "),
            "{err}"
        );
    }

    #[test]
    fn a_temp_dir_is_removed_on_drop_and_on_panic() {
        let dir = TempDir::new("fsio-drop").unwrap();
        std::fs::write(dir.join("f"), b"x").unwrap();
        let path = dir.to_path_buf();
        drop(dir);
        assert!(!path.exists());
        let path = std::panic::catch_unwind(|| {
            let dir = TempDir::new("fsio-panic").unwrap();
            std::fs::write(dir.join("f"), b"x").unwrap();
            let path = dir.to_path_buf();
            std::panic::panic_any(path);
        })
        .unwrap_err()
        .downcast::<std::path::PathBuf>()
        .unwrap();
        assert!(!path.exists(), "{}", path.display());
    }
}
