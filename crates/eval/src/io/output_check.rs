//! The output-safety check every subcommand runs before any work (docs/cli.md "Safety
//! rules"): no output may be an input, lie inside an input directory (a flight, a dataset
//! split, a model directory, a cache), contain an input (replacing the output would delete
//! it), or coincide with or contain another output; and every output must be replaceable by
//! its kind ([`check_replaceable`]: only regular files and directories, never a device, FIFO or
//! symbolic link).
//!
//! Paths are compared after resolving them: the longest existing prefix is canonicalised
//! (symbolic links and `..` resolved) and the rest appended lexically; existing files are also
//! compared by device and inode, so a hard link to an input counts as the input.

use std::path::{Component, Path, PathBuf};

use crate::io::atomic::{OutputKind, check_replaceable};
use crate::io::error::{IoError, Result};

/// A path a command reads, with the option that named it (for messages).
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    /// Command-line option, e.g. `--in`.
    pub flag: &'a str,
    /// The path (file or directory).
    pub path: &'a Path,
}

/// A path a command writes, with the option that named it and what it will be.
#[derive(Debug, Clone, Copy)]
pub struct Output<'a> {
    /// Command-line option, e.g. `--out`.
    pub flag: &'a str,
    /// The path.
    pub path: &'a Path,
    /// File or directory.
    pub kind: OutputKind,
}

impl<'a> Input<'a> {
    /// An input named by `flag`.
    #[must_use]
    pub fn new(flag: &'a str, path: &'a Path) -> Self {
        Self { flag, path }
    }
}

impl<'a> Output<'a> {
    /// A file output named by `flag`.
    #[must_use]
    pub fn file(flag: &'a str, path: &'a Path) -> Self {
        Self { flag, path, kind: OutputKind::File }
    }

    /// A directory output named by `flag`.
    #[must_use]
    pub fn dir(flag: &'a str, path: &'a Path) -> Self {
        Self { flag, path, kind: OutputKind::Dir }
    }
}

/// `path` made absolute and resolved as far as it exists (see the module doc).
fn resolve(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_owned()
    } else {
        std::env::current_dir().map_or_else(|_| path.to_owned(), |cwd| cwd.join(path))
    };
    let mut existing = abs.as_path();
    let mut rest: Vec<Component<'_>> = Vec::new();
    let base = loop {
        if let Ok(c) = existing.canonicalize() {
            break c;
        }
        let (Some(parent), Some(last)) = (existing.parent(), existing.components().next_back()) else {
            break existing.to_owned();
        };
        rest.push(last);
        existing = parent;
    };
    let mut out = base;
    for c in rest.into_iter().rev() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// Device and inode of an existing path (following links), to recognise hard links.
#[cfg(unix)]
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt as _;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

#[cfg(not(unix))]
fn file_id(_path: &Path) -> Option<(u64, u64)> {
    None
}

/// Checks `outputs` against `inputs` and each other (rules in the module doc).
///
/// # Errors
/// [`IoError::Unsafe`] naming the output, the option of the input or output it collides with,
/// and why.
pub fn check_outputs(inputs: &[Input<'_>], outputs: &[Output<'_>]) -> Result<()> {
    let unsafe_err = |o: &Output<'_>, msg: String| IoError::Unsafe { path: o.path.to_owned(), msg };
    let inputs: Vec<(Input<'_>, PathBuf)> = inputs.iter().map(|i| (*i, resolve(i.path))).collect();
    let mut seen: Vec<(Output<'_>, PathBuf)> = Vec::new();
    for o in outputs {
        check_replaceable(o.path, o.kind)?;
        let ro = resolve(o.path);
        let o_id = file_id(o.path);
        for (i, ri) in &inputs {
            let same = ro == *ri || (o_id.is_some() && o_id == file_id(i.path));
            if same {
                return Err(unsafe_err(
                    o,
                    format!("{} is also the input {} {}; it would be overwritten", o.flag, i.flag, i.path.display()),
                ));
            }
            if ro.starts_with(ri) {
                return Err(unsafe_err(
                    o,
                    format!(
                        "{} lies inside {} {}, which is read; write it elsewhere",
                        o.flag,
                        i.flag,
                        i.path.display()
                    ),
                ));
            }
            if ri.starts_with(&ro) {
                return Err(unsafe_err(
                    o,
                    format!(
                        "{} contains the input {} {}, which replacing it would delete",
                        o.flag,
                        i.flag,
                        i.path.display()
                    ),
                ));
            }
        }
        for (other, rother) in &seen {
            if ro.starts_with(rother) || rother.starts_with(&ro) {
                return Err(unsafe_err(
                    o,
                    format!(
                        "{} and {} {} are the same path or one holds the other",
                        o.flag,
                        other.flag,
                        other.path.display()
                    ),
                ));
            }
        }
        seen.push((*o, ro));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_may_not_touch_inputs_or_each_other() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir_all(d.join("ds/train")).unwrap();
        std::fs::create_dir_all(d.join("model")).unwrap();
        std::fs::write(d.join("in.csv"), "t\n").unwrap();
        std::fs::write(d.join("model/quadformer.safetensors"), "w").unwrap();
        let e = |inputs: &[Input<'_>], outputs: &[Output<'_>]| check_outputs(inputs, outputs).unwrap_err().to_string();
        let input = d.join("in.csv");
        let dotted = d.join("ds/../in.csv");
        let msg = e(&[Input::new("--in", &input)], &[Output::file("--out", &dotted)]);
        assert!(msg.contains("--out is also the input --in"), "{msg}");
        let weights = d.join("model/quadformer.safetensors");
        let model = d.join("model");
        let msg = e(&[Input::new("--model", &model)], &[Output::file("--out", &weights)]);
        assert!(msg.contains("--out lies inside --model"), "{msg}");
        let train = d.join("ds/train");
        let ds = d.join("ds");
        let msg = e(&[Input::new("--train", &train)], &[Output::dir("--out", &ds)]);
        assert!(msg.contains("--out contains the input --train"), "{msg}");
        let r = d.join("r.csv");
        let msg = e(&[], &[Output::file("--out", &r), Output::file("--estimates", &r)]);
        assert!(msg.contains("--estimates and --out"), "{msg}");
        let ok = d.join("elsewhere/out.csv");
        check_outputs(&[Input::new("--in", &input), Input::new("--model", &model)], &[Output::file("--out", &ok)])
            .unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_hard_link_to_an_input_is_the_input() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.csv");
        let link = dir.path().join("link.csv");
        std::fs::write(&input, "t\n").unwrap();
        std::fs::hard_link(&input, &link).unwrap();
        let msg =
            check_outputs(&[Input::new("--in", &input)], &[Output::file("--out", &link)]).unwrap_err().to_string();
        assert!(msg.contains("also the input"), "{msg}");
    }
}
