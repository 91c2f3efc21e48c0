//! Atomic output, the one implementation every writer of QUADFormer-rs uses: a file is written
//! to a temporary file in its target directory and renamed into place; a directory is filled
//! as a temporary sibling and renamed. On any error the temporary is removed, so no partly
//! written output is ever visible under the final name (docs/cli.md "Safety rules";
//! docs/decisions/071-atomic-output.md).
//!
//! Rules kept here, for every output:
//! - only a regular file (by a file writer) or a directory (by a directory writer) is ever
//!   replaced; a symbolic link, device, FIFO or socket under the final name is an error, and
//!   so is an ancestor of the final name that exists but is not a directory;
//! - temporaries are named `.qftmp-<pid>-<random>` (at most 30 bytes, whatever the final
//!   name, so a final name of up to 255 bytes works); temporaries of a process that no longer
//!   runs, left by a kill, are removed from the target directory before the next write there.

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::io::error::{IoError, Result};

/// Prefix of every temporary file or directory this module creates.
pub const TEMP_PREFIX: &str = ".qftmp-";

/// The directory that holds `path` (`.` for a bare file name).
fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    }
}

/// What an output path will be replaced with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    /// A regular file.
    File,
    /// A directory.
    Dir,
}

/// A description of what is at `meta`, for error messages.
fn kind_name(ft: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        if ft.is_block_device() || ft.is_char_device() {
            return "a device";
        }
        if ft.is_fifo() {
            return "a FIFO";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_symlink() {
        "a symbolic link"
    } else if ft.is_dir() {
        "a directory"
    } else if ft.is_file() {
        "a regular file"
    } else {
        "a special file"
    }
}

/// Checks that `path` may be replaced by an output of `kind`: it does not exist, or it is a
/// regular file (for [`OutputKind::File`]) or a directory, not a symbolic link (for
/// [`OutputKind::Dir`]); and every ancestor that exists is a directory.
///
/// # Errors
/// [`IoError::Unsafe`] naming the path and what is there.
pub fn check_replaceable(path: &Path, kind: OutputKind) -> Result<()> {
    let unsafe_err = |p: &Path, msg: String| IoError::Unsafe { path: p.to_owned(), msg };
    match std::fs::symlink_metadata(path) {
        Ok(meta) => {
            let ft = meta.file_type();
            let ok = match kind {
                OutputKind::File => ft.is_file(),
                OutputKind::Dir => ft.is_dir(),
            };
            if !ok {
                let want = if kind == OutputKind::File { "regular files" } else { "directories" };
                return Err(unsafe_err(path, format!("is {}; only {want} are replaced by this output", kind_name(ft))));
            }
        }
        // An ancestor that is not a directory is reported below.
        Err(e) if matches!(e.kind(), std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory) => {}
        Err(source) => return Err(IoError::Fs { path: path.to_owned(), op: "inspect", source }),
    }
    for ancestor in path.ancestors().skip(1).filter(|a| !a.as_os_str().is_empty()) {
        // `metadata` follows links: a symlink to a directory is a fine parent.
        match std::fs::metadata(ancestor) {
            Ok(meta) if meta.is_dir() => break,
            Ok(meta) => {
                return Err(unsafe_err(
                    ancestor,
                    format!(
                        "is {}, not a directory, so {} cannot be created",
                        kind_name(meta.file_type()),
                        path.display()
                    ),
                ));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => return Err(IoError::Fs { path: ancestor.to_owned(), op: "inspect", source }),
        }
    }
    Ok(())
}

/// Creates `dir` and its parents.
fn create_dir_all(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Fs { path: dir.to_owned(), op: "create directory", source })
}

/// The name prefix of this process's temporaries: [`TEMP_PREFIX`], the process id and `-`.
fn own_prefix() -> String {
    format!("{TEMP_PREFIX}{}-", std::process::id())
}

/// A temporary file in `dir` named after this module's rule, ending in `suffix`.
fn temp_file_in(dir: &Path, suffix: &str) -> Result<tempfile::NamedTempFile> {
    let prefix = own_prefix();
    tempfile::Builder::new()
        .prefix(&prefix)
        .suffix(suffix)
        .rand_bytes(6)
        .tempfile_in(dir)
        .map_err(|source| IoError::Fs { path: dir.to_owned(), op: "create a temporary file in", source })
}

/// A temporary directory in `dir` named after this module's rule.
fn temp_dir_in(dir: &Path) -> Result<tempfile::TempDir> {
    let prefix = own_prefix();
    tempfile::Builder::new().prefix(&prefix).rand_bytes(6).tempdir_in(dir).map_err(|source| IoError::Fs {
        path: dir.to_owned(),
        op: "create a temporary directory in",
        source,
    })
}

/// The process id encoded in a temporary's name, if `name` is one of this module's.
fn temp_owner(name: &std::ffi::OsStr) -> Option<u32> {
    let rest = name.to_str()?.strip_prefix(TEMP_PREFIX)?;
    rest.split('-').next()?.parse().ok()
}

/// Whether process `pid` still runs (Linux: `/proc/<pid>` exists). Where `/proc` is not
/// available every other process counts as running, so nothing is removed.
fn process_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new("/proc").join(pid.to_string()).exists()
}

/// Removes the temporaries in `dir` left by processes that no longer run (a killed earlier
/// write), once per directory and process (a process that is gone leaves no new ones).
/// Failures are ignored: cleaning is a courtesy, never a reason to fail the output.
pub fn remove_stale_temps(dir: &Path) {
    static CLEANED: std::sync::Mutex<Option<std::collections::HashSet<PathBuf>>> = std::sync::Mutex::new(None);
    let key = dir.canonicalize().unwrap_or_else(|_| dir.to_owned());
    if let Ok(mut seen) = CLEANED.lock()
        && !seen.get_or_insert_with(Default::default).insert(key)
    {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let me = std::process::id();
    for entry in entries.flatten() {
        let Some(pid) = temp_owner(&entry.file_name()) else { continue };
        if pid == me || process_alive(pid) {
            continue;
        }
        let path = entry.path();
        match entry.file_type() {
            Ok(ft) if ft.is_dir() => {
                let _ = std::fs::remove_dir_all(&path);
            }
            Ok(_) => {
                let _ = std::fs::remove_file(&path);
            }
            Err(_) => {}
        }
    }
}

/// Writes `path` atomically: `write` receives a temporary file in the same directory and
/// returns it once filled; it is then synced and renamed to `path` (replacing an old regular
/// file). Missing parent directories are created.
///
/// # Errors
/// [`IoError::Unsafe`] if `path` is not replaceable ([`check_replaceable`]); [`IoError::Fs`]
/// when the temporary cannot be created, synced or renamed, or whatever `write` returns; in
/// every error case `path` is untouched and the temporary removed.
pub fn write_file_atomic(path: &Path, write: impl FnOnce(File) -> Result<File>) -> Result<()> {
    stage_file(path, write)?.commit()
}

/// A complete file in its temporary, to be renamed to its final name by [`Staged::commit`] or
/// [`commit_all`]; dropped uncommitted, the temporary is removed.
#[derive(Debug)]
pub struct Staged {
    tmp: tempfile::NamedTempFile,
    path: PathBuf,
}

impl Staged {
    /// Renames the file into place (checking again that the final name is replaceable).
    ///
    /// # Errors
    /// [`IoError::Unsafe`] or [`IoError::Fs`] naming the final path.
    pub fn commit(self) -> Result<()> {
        check_replaceable(&self.path, OutputKind::File)?;
        let path = self.path;
        self.tmp.persist(&path).map_err(|e| IoError::Fs { path, op: "rename into place", source: e.error })?;
        Ok(())
    }
}

/// Writes `path`'s contents as [`write_file_atomic`] does, but leaves the file in its
/// temporary: several outputs of one command are staged, then committed together
/// ([`commit_all`]), so a failure while writing any of them leaves none.
///
/// # Errors
/// As [`write_file_atomic`].
pub fn stage_file(path: &Path, write: impl FnOnce(File) -> Result<File>) -> Result<Staged> {
    check_replaceable(path, OutputKind::File)?;
    let dir = parent_of(path);
    create_dir_all(&dir)?;
    remove_stale_temps(&dir);
    let tmp = temp_file_in(&dir, "")?;
    // Temporary files are created private (0600); the output is an ordinary data file.
    set_mode(tmp.path(), 0o644)?;
    let file = tmp.reopen().map_err(|source| IoError::Fs { path: path.to_owned(), op: "open", source })?;
    let file = write(file)?;
    file.sync_all().map_err(|source| IoError::Fs { path: path.to_owned(), op: "sync", source })?;
    Ok(Staged { tmp, path: path.to_owned() })
}

/// Commits staged files: every final name is checked first, then each is renamed into place.
///
/// # Errors
/// As [`Staged::commit`]; when a check fails, nothing is renamed.
pub fn commit_all(files: Vec<Staged>) -> Result<()> {
    for f in &files {
        check_replaceable(&f.path, OutputKind::File)?;
    }
    files.into_iter().try_for_each(Staged::commit)
}

/// Writes `path` atomically through a temporary *path* (ending in `suffix`, e.g. `.png` for
/// writers that pick a format from the extension): `write` creates the file's contents at the
/// path it is given; the result is renamed to `path`. Checks and errors as
/// [`write_file_atomic`]; `E` is the caller's error type.
///
/// # Errors
/// As [`write_file_atomic`], or whatever `write` returns.
pub fn write_path_atomic<E: From<IoError>>(
    path: &Path,
    suffix: &str,
    write: impl FnOnce(&Path) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    check_replaceable(path, OutputKind::File)?;
    let dir = parent_of(path);
    create_dir_all(&dir)?;
    remove_stale_temps(&dir);
    let tmp = temp_file_in(&dir, suffix)?;
    // Temporary files are created private (0600); the output is an ordinary data file.
    set_mode(tmp.path(), 0o644)?;
    write(tmp.path())?;
    // The final name may have changed kind while we worked: check again just before renaming.
    check_replaceable(path, OutputKind::File)?;
    tmp.persist(path).map_err(|e| IoError::Fs { path: path.to_owned(), op: "rename into place", source: e.error })?;
    Ok(())
}

/// Writes `bytes` to `path` atomically.
///
/// # Errors
/// As [`write_file_atomic`].
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    stage_bytes(path, bytes)?.commit()
}

/// Writes `bytes` into `path`'s temporary, to be committed with the other outputs of a command
/// ([`commit_all`]).
///
/// # Errors
/// As [`stage_file`].
pub fn stage_bytes(path: &Path, bytes: &[u8]) -> Result<Staged> {
    use std::io::Write as _;
    stage_file(path, |mut f| {
        f.write_all(bytes).map_err(|source| IoError::Fs { path: path.to_owned(), op: "write", source })?;
        Ok(f)
    })
}

/// Writes the bytes of `text` to `path` atomically.
///
/// # Errors
/// As [`write_file_atomic`].
pub fn write_text_atomic(path: &Path, text: &str) -> Result<()> {
    write_bytes_atomic(path, text.as_bytes())
}

/// What to do when the output directory already exists.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overwrite {
    /// Refuse with an error if the directory exists and is not empty.
    Refuse,
    /// Replace the old directory (it is removed only after the new one is complete).
    Replace,
}

/// Checks, before any work, that directory `dir` may be written with `overwrite`: it is
/// replaceable ([`check_replaceable`]) and, with [`Overwrite::Refuse`], absent or empty.
///
/// # Errors
/// [`IoError::Unsafe`] or [`IoError::Inconsistent`] naming `dir`.
pub fn check_dir_output(dir: &Path, overwrite: Overwrite) -> Result<()> {
    check_replaceable(dir, OutputKind::Dir)?;
    let non_empty = dir.is_dir()
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
    Ok(())
}

/// Creates directory `dir` atomically: `fill` writes into a temporary sibling directory,
/// which is renamed to `dir` once `fill` succeeded.
///
/// An existing empty `dir` is replaced silently; a non-empty one only with
/// [`Overwrite::Replace`], and then the old contents are removed after the rename.
///
/// # Errors
/// As [`check_dir_output`] (checked before any work); [`IoError::Fs`] on file-system failure;
/// whatever `fill` returns. On error, `dir` is as it was and the temporary is removed.
pub fn write_dir_atomic<E: From<IoError>>(
    dir: &Path,
    overwrite: Overwrite,
    fill: impl FnOnce(&Path) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    check_dir_output(dir, overwrite)?;
    let parent = parent_of(dir);
    create_dir_all(&parent)?;
    remove_stale_temps(&parent);
    let tmp = temp_dir_in(&parent)?;
    set_mode(tmp.path(), 0o755)?;
    fill(tmp.path())?;
    check_dir_output(dir, overwrite)?;
    // Move any old directory aside first, so that the rename of the new one cannot fail on a
    // non-empty target, and delete it only once the new one is in place.
    let old = if dir.exists() {
        let aside = temp_dir_in(&parent)?;
        let aside_target = aside.path().join("replaced");
        std::fs::rename(dir, &aside_target).map_err(|source| IoError::Fs {
            path: dir.to_owned(),
            op: "move the old directory aside",
            source,
        })?;
        Some((aside, aside_target))
    } else {
        None
    };
    if let Err(source) = std::fs::rename(tmp.path(), dir) {
        // Put the old directory back; the new one is removed when `tmp` drops.
        if let Some((_, aside_target)) = &old {
            let _ = std::fs::rename(aside_target, dir);
        }
        return Err(IoError::Fs { path: dir.to_owned(), op: "rename into place", source }.into());
    }
    // The temporary's path is gone (renamed); keep `TempDir` from removing anything.
    let _ = tmp.keep();
    drop(old); // removes the old directory
    Ok(())
}

/// Adds files to directory `dir` (created if missing) all or none: `fill` writes them into a
/// temporary sibling directory; once it succeeded, each entry is moved into `dir`, replacing
/// a regular file or directory of the same name. On error nothing in `dir` changes.
///
/// # Errors
/// [`IoError::Unsafe`] if `dir` is not a directory or an entry would replace something other
/// than a regular file or directory; [`IoError::Fs`] on file-system failure; whatever `fill`
/// returns.
pub fn write_into_dir_atomic<E: From<IoError>>(
    dir: &Path,
    fill: impl FnOnce(&Path) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    if std::fs::metadata(dir).is_ok_and(|m| !m.is_dir()) {
        return Err(IoError::Unsafe { path: dir.to_owned(), msg: "is not a directory".into() }.into());
    }
    check_replaceable(&dir.join("x"), OutputKind::File)?;
    let parent = parent_of(dir);
    create_dir_all(&parent)?;
    remove_stale_temps(&parent);
    let tmp = temp_dir_in(&parent)?;
    set_mode(tmp.path(), 0o755)?;
    fill(tmp.path())?;
    let list = |p: &Path| -> Result<Vec<std::fs::DirEntry>> {
        std::fs::read_dir(p).and_then(Iterator::collect).map_err(|source| IoError::Fs {
            path: p.to_owned(),
            op: "list",
            source,
        })
    };
    let entries = list(tmp.path())?;
    for entry in &entries {
        let kind = if entry.path().is_dir() { OutputKind::Dir } else { OutputKind::File };
        check_replaceable(&dir.join(entry.file_name()), kind)?;
    }
    create_dir_all(dir)?;
    for entry in entries {
        let target = dir.join(entry.file_name());
        if entry.path().is_dir() && target.is_dir() {
            let _ = std::fs::remove_dir_all(&target);
        }
        std::fs::rename(entry.path(), &target).map_err(|source| IoError::Fs {
            path: target.clone(),
            op: "rename into place",
            source,
        })?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_are_short_and_recognised() {
        let dir = tempfile::tempdir().unwrap();
        let f = temp_file_in(dir.path(), "").unwrap();
        let name = f.path().file_name().unwrap().to_owned();
        assert!(name.len() <= 30, "{name:?}");
        assert_eq!(temp_owner(&name), Some(std::process::id()));
        assert_eq!(temp_owner(std::ffi::OsStr::new(".gps.csv.tmp")), None);
    }

    #[test]
    fn stale_temps_of_dead_processes_are_removed_and_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        // PID 0 is never a user process: a stand-in for a killed writer.
        let stale_file = dir.path().join(format!("{TEMP_PREFIX}0-abcdef"));
        let stale_dir = dir.path().join(format!("{TEMP_PREFIX}0-ghijkl"));
        let mine = dir.path().join(format!("{TEMP_PREFIX}{}-mnopqr", std::process::id()));
        std::fs::write(&stale_file, b"x").unwrap();
        std::fs::create_dir(&stale_dir).unwrap();
        std::fs::write(stale_dir.join("imu.csv"), b"x").unwrap();
        std::fs::write(&mine, b"x").unwrap();
        write_text_atomic(&dir.path().join("out.csv"), "t\n").unwrap();
        assert!(!stale_file.exists() && !stale_dir.exists());
        assert!(mine.exists());
    }

    #[test]
    fn a_long_final_name_works() {
        let dir = tempfile::tempdir().unwrap();
        let name = format!("{}.csv", "a".repeat(251));
        write_text_atomic(&dir.path().join(&name), "t\n").unwrap();
        assert_eq!(std::fs::read_to_string(dir.path().join(name)).unwrap(), "t\n");
    }

    #[cfg(unix)]
    #[test]
    fn only_regular_files_and_directories_are_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("target.csv");
        std::fs::write(&target, "keep").unwrap();
        let link = dir.path().join("link.csv");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = write_text_atomic(&link, "x").unwrap_err().to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
        let e = write_text_atomic(Path::new("/dev/null"), "x").unwrap_err().to_string();
        assert!(e.contains("/dev/null: is a device"), "{e}");
        let e = write_text_atomic(dir.path(), "x").unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        let e = write_text_atomic(&target.join("sub.csv"), "x").unwrap_err().to_string();
        assert!(e.contains("target.csv: is a regular file, not a directory"), "{e}");
        let e = write_dir_atomic(&target, Overwrite::Replace, |_| Ok::<(), IoError>(())).unwrap_err().to_string();
        assert!(e.contains("is a regular file; only directories"), "{e}");
        let dlink = dir.path().join("dlink");
        std::os::unix::fs::symlink(dir.path(), &dlink).unwrap();
        let e = write_dir_atomic(&dlink, Overwrite::Replace, |_| Ok::<(), IoError>(())).unwrap_err().to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        // Nothing was left behind.
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(TEMP_PREFIX))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn a_failed_fill_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let r = write_dir_atomic(&out, Overwrite::Refuse, |tmp| {
            std::fs::write(tmp.join("a"), "x").unwrap();
            Err(IoError::Inconsistent { path: tmp.to_owned(), msg: "boom".into() })
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn files_are_added_to_a_directory_all_or_none() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let r = write_into_dir_atomic(&out, |tmp| {
            std::fs::create_dir(tmp.join("plots")).unwrap();
            std::fs::write(tmp.join("plots/a.png"), "x").unwrap();
            Err(IoError::Inconsistent { path: tmp.to_owned(), msg: "flight failed".into() })
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "neither out/ nor a temporary");
        std::fs::create_dir_all(out.join("datasets")).unwrap();
        write_into_dir_atomic(&out, |tmp| {
            std::fs::create_dir(tmp.join("plots")).unwrap();
            std::fs::write(tmp.join("plots/a.png"), "x").unwrap();
            write_text_atomic(&tmp.join("scenarios.csv"), "t\n")
        })
        .unwrap();
        assert!(
            out.join("plots/a.png").is_file() && out.join("scenarios.csv").is_file() && out.join("datasets").is_dir()
        );
    }

    #[test]
    fn staged_files_appear_together_or_not_at_all() {
        use std::io::Write as _;
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
        let fill = |mut f: File| -> Result<File> {
            f.write_all(b"t\n").unwrap();
            Ok(f)
        };
        let first = stage_file(&a, fill).unwrap();
        let failed = stage_file(&b, |_| Err(IoError::Inconsistent { path: b.clone(), msg: "boom".into() }));
        assert!(failed.is_err());
        drop(first); // the command gives up: nothing was committed
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        commit_all(vec![stage_file(&a, fill).unwrap(), stage_file(&b, fill).unwrap()]).unwrap();
        assert!(a.is_file() && b.is_file());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}
