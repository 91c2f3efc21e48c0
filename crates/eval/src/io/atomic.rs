//! Atomic output: a file is written to a temporary file in its target directory and renamed
//! into place; a flight directory is filled in a temporary sibling directory and renamed. On
//! any error the temporary is removed, so no partly written output is ever visible under the
//! final name (HOUSE_STYLE rule 14; DESIGN.md "What done looks like").

use std::ffi::OsString;
use std::fs::File;
use std::path::{Path, PathBuf};

use crate::io::error::{IoError, Result};

/// The directory that holds `path` (`.` for a bare file name).
fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    }
}

/// A hidden temporary-name prefix derived from the final name, e.g. `.gps.csv.tmp`.
fn tmp_prefix(path: &Path) -> OsString {
    let mut prefix = OsString::from(".");
    prefix.push(path.file_name().unwrap_or_else(|| std::ffi::OsStr::new("out")));
    prefix.push(".tmp");
    prefix
}

/// Writes `path` atomically: `write` receives a temporary file in the same directory and
/// returns it once filled; it is then synced and renamed to `path` (replacing any old file).
/// Missing parent directories are created.
///
/// # Errors
/// [`IoError::Fs`] when the temporary cannot be created, synced or renamed, or whatever
/// `write` returns; in every error case `path` is untouched and the temporary removed.
pub fn write_file_atomic(path: &Path, write: impl FnOnce(File) -> Result<File>) -> Result<()> {
    let dir = parent_of(path);
    std::fs::create_dir_all(&dir).map_err(|source| IoError::Fs {
        path: dir.clone(),
        op: "create directory",
        source,
    })?;
    let tmp = tempfile::Builder::new().prefix(&tmp_prefix(path)).tempfile_in(&dir).map_err(|source| IoError::Fs {
        path: dir.clone(),
        op: "create a temporary file in",
        source,
    })?;
    // Temporary files are created private (0600); the output is an ordinary data file.
    set_mode(tmp.path(), 0o644)?;
    let handle =
        tmp.as_file().try_clone().map_err(|source| IoError::Fs { path: path.to_owned(), op: "open", source })?;
    let handle = write(handle)?;
    handle.sync_all().map_err(|source| IoError::Fs { path: path.to_owned(), op: "sync", source })?;
    drop(handle);
    tmp.persist(path).map_err(|e| IoError::Fs { path: path.to_owned(), op: "rename into place", source: e.error })?;
    Ok(())
}

/// Writes the bytes of `text` to `path` atomically.
///
/// # Errors
/// As [`write_file_atomic`].
pub fn write_text_atomic(path: &Path, text: &str) -> Result<()> {
    use std::io::Write as _;
    write_file_atomic(path, |mut f| {
        f.write_all(text.as_bytes()).map_err(|source| IoError::Fs { path: path.to_owned(), op: "write", source })?;
        Ok(f)
    })
}

/// What to do when the output directory already exists.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overwrite {
    /// Refuse with an error if the directory exists and is not empty.
    Refuse,
    /// Replace the old directory (it is removed only after the new one is complete).
    Replace,
}

/// Creates directory `dir` atomically: `fill` writes into a temporary sibling directory,
/// which is renamed to `dir` once `fill` succeeded.
///
/// An existing empty `dir` is replaced silently; a non-empty one only with
/// [`Overwrite::Replace`], and then the old contents are removed after the rename.
///
/// # Errors
/// [`IoError::Inconsistent`] if `dir` exists, is not empty and `overwrite` is
/// [`Overwrite::Refuse`] (checked before any work); [`IoError::Fs`] on file-system failure;
/// whatever `fill` returns. On error, `dir` is as it was and the temporary is removed.
pub fn write_dir_atomic(dir: &Path, overwrite: Overwrite, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let exists = dir.exists();
    let non_empty = exists
        && std::fs::read_dir(dir)
            .map_err(|source| IoError::Fs { path: dir.to_owned(), op: "list", source })?
            .next()
            .is_some();
    if non_empty && overwrite == Overwrite::Refuse {
        return Err(IoError::Inconsistent {
            path: dir.to_owned(),
            msg: "output directory exists and is not empty (choose another or allow replacing it)".into(),
        });
    }
    let parent = parent_of(dir);
    std::fs::create_dir_all(&parent).map_err(|source| IoError::Fs {
        path: parent.clone(),
        op: "create directory",
        source,
    })?;
    let tmp = tempfile::Builder::new().prefix(&tmp_prefix(dir)).tempdir_in(&parent).map_err(|source| IoError::Fs {
        path: parent.clone(),
        op: "create a temporary directory in",
        source,
    })?;
    set_mode(tmp.path(), 0o755)?;
    fill(tmp.path())?;
    // Move any old directory aside first, so that the rename of the new one cannot fail on a
    // non-empty target, and delete it only once the new one is in place.
    let old = if exists {
        let aside = tempfile::Builder::new()
            .prefix(&tmp_prefix(dir))
            .suffix(".old")
            .tempdir_in(&parent)
            .map_err(|source| IoError::Fs { path: parent.clone(), op: "create a temporary directory in", source })?
            .keep();
        let aside_target = aside.join("replaced");
        std::fs::rename(dir, &aside_target).map_err(|source| IoError::Fs {
            path: dir.to_owned(),
            op: "move the old directory aside",
            source,
        })?;
        Some((aside, aside_target))
    } else {
        None
    };
    let tmp_path = tmp.keep();
    if let Err(source) = std::fs::rename(&tmp_path, dir) {
        // Put the old directory back; the new one stays removed.
        if let Some((_, aside_target)) = &old {
            let _ = std::fs::rename(aside_target, dir);
        }
        let _ = std::fs::remove_dir_all(&tmp_path);
        return Err(IoError::Fs { path: dir.to_owned(), op: "rename into place", source });
    }
    if let Some((aside, _)) = old {
        let _ = std::fs::remove_dir_all(aside);
    }
    Ok(())
}

/// Gives a temporary file or directory ordinary permissions, masked by the process umask as
/// a normally created file would be (Unix only; a no-op elsewhere).
fn set_mode(path: &Path, mode: u32) -> Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        let umask = current_umask();
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode & !umask))
            .map_err(|source| IoError::Fs { path: path.to_owned(), op: "set permissions of", source })?;
    }
    #[cfg(not(unix))]
    let _ = (path, mode);
    Ok(())
}

/// The process umask, read from `/proc/self/status` where available (Linux ≥ 4.7); 0o022,
/// the usual default, otherwise. Reading it this way avoids `umask(2)`, which would change it.
#[cfg(unix)]
fn current_umask() -> u32 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find_map(|l| l.strip_prefix("Umask:")).and_then(|v| u32::from_str_radix(v.trim(), 8).ok())
        })
        .unwrap_or(0o022)
}
