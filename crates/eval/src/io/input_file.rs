//! Opening input files within their budgets (docs/cli.md "Safety rules"): an input is read
//! only from a regular file (a symbolic link to one is fine), never from a device or FIFO,
//! which could stream without end, and only up to a stated size, checked before reading.

use std::fs::File;
use std::io::Read as _;
use std::path::Path;

use crate::io::error::{IoError, Result};

/// Budget of a text input (TOML config, JSON manifest): 16 MiB.
pub const MAX_TEXT_BYTES: u64 = 16 << 20;
/// Budget of a CSV input: 2 GiB, about 20 M IMU rows (twice a simulated flight's budget).
pub const MAX_CSV_BYTES: u64 = 2 << 30;

/// Opens `path` for reading after checking that it is a regular file of at most `max_bytes`.
///
/// # Errors
/// [`IoError::Fs`] if it cannot be opened; [`IoError::Unsafe`] naming the path when it is not
/// a regular file or exceeds the budget.
pub fn open_input(path: &Path, max_bytes: u64) -> Result<File> {
    let file = File::open(path).map_err(|source| IoError::Fs { path: path.to_owned(), op: "open", source })?;
    let meta = file.metadata().map_err(|source| IoError::Fs { path: path.to_owned(), op: "inspect", source })?;
    if !meta.is_file() {
        let what = if meta.is_dir() { "a directory" } else { "not a regular file (a device, FIFO or socket)" };
        return Err(IoError::Unsafe {
            path: path.to_owned(),
            msg: format!("is {what}; inputs are read from regular files"),
        });
    }
    if meta.len() > max_bytes {
        return Err(IoError::Unsafe {
            path: path.to_owned(),
            msg: format!("{} bytes exceed the budget of {max_bytes} bytes for this input", meta.len()),
        });
    }
    Ok(file)
}

/// Reads a text input (config or manifest) of at most [`MAX_TEXT_BYTES`], as UTF-8.
///
/// # Errors
/// As [`open_input`]; [`IoError::Fs`] if reading fails or the text is not UTF-8.
pub fn read_text(path: &Path) -> Result<String> {
    let file = open_input(path, MAX_TEXT_BYTES)?;
    let mut text = String::new();
    // `take` also bounds a file that grows while it is read.
    file.take(MAX_TEXT_BYTES + 1).read_to_string(&mut text).map_err(|source| IoError::Fs {
        path: path.to_owned(),
        op: "read",
        source,
    })?;
    if text.len() as u64 > MAX_TEXT_BYTES {
        return Err(IoError::Unsafe {
            path: path.to_owned(),
            msg: format!("more than the budget of {MAX_TEXT_BYTES} bytes for this input"),
        });
    }
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn devices_and_directories_are_not_inputs() {
        let e = read_text(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(e.contains("/dev/zero: is not a regular file"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let e = read_text(dir.path()).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        let small = dir.path().join("c.toml");
        std::fs::write(&small, "seed = 1\n").unwrap();
        assert_eq!(read_text(&small).unwrap(), "seed = 1\n");
        let e = open_input(&small, 3).unwrap_err().to_string();
        assert!(e.contains("9 bytes exceed the budget of 3 bytes"), "{e}");
    }
}
