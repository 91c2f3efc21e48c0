//! Errors of the file formats: every variant names the file, and where it applies the line
//! (1-based, as an editor shows it) and the column (1-based index and header name).

use std::path::PathBuf;

use ekf_residue::ResidueError;

/// Reading or writing a flight directory, a residue file or a config failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// The operating system refused a file operation.
    #[error("{}: cannot {op}: {source}", path.display())]
    Fs {
        /// File or directory concerned.
        path: PathBuf,
        /// What was attempted, e.g. "open", "rename".
        op: &'static str,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// An output would replace or reach something it must not (a device, FIFO or symbolic
    /// link; an input; a model's own file), or cannot be created where asked; or an input is
    /// not a regular file or exceeds its size budget.
    #[error("{}: {msg}", path.display())]
    Unsafe {
        /// The output path (or the ancestor) concerned.
        path: PathBuf,
        /// What is there, or which input it would overwrite.
        msg: String,
    },
    /// A required file is absent.
    #[error("{}: missing file ({why})", path.display())]
    MissingFile {
        /// The path that was expected.
        path: PathBuf,
        /// Why it is needed.
        why: String,
    },
    /// The header lacks a required column.
    #[error("{}: line 1: missing column `{column}` (header has: {found})", path.display(), found = found.join(","))]
    MissingColumn {
        /// The CSV file.
        path: PathBuf,
        /// The column that is required.
        column: String,
        /// The columns the header has.
        found: Vec<String>,
    },
    /// Several required columns are absent from the header.
    #[error(
        "{}: line 1: missing columns {} (header has: {}); another tool's names can be mapped with --columns THEIRS=OURS,...",
        path.display(),
        columns.iter().map(|c| format!("`{c}`")).collect::<Vec<_>>().join(", "),
        found.join(",")
    )]
    MissingColumns {
        /// The CSV file.
        path: PathBuf,
        /// Every required column that is absent.
        columns: Vec<String>,
        /// The columns the header has.
        found: Vec<String>,
    },
    /// The header is malformed (empty, duplicate names, an unknown column).
    #[error("{}: line {line}: {msg}", path.display())]
    Header {
        /// The CSV file.
        path: PathBuf,
        /// Line of the header (1 unless comment lines precede it).
        line: u64,
        /// What is wrong.
        msg: String,
    },
    /// A record does not have as many fields as the header.
    #[error("{}: line {line}: expected {expected} fields (as in the header), found {found}", path.display())]
    FieldCount {
        /// The CSV file.
        path: PathBuf,
        /// Line of the record.
        line: u64,
        /// Number of header columns.
        expected: usize,
        /// Number of fields on this line.
        found: usize,
    },
    /// One field is not acceptable (not a number, NaN, out of order, ...).
    #[error("{}: line {line}, column {column} (`{field}`): {msg}", path.display())]
    Field {
        /// The CSV file.
        path: PathBuf,
        /// Line of the record.
        line: u64,
        /// Column index, 1-based.
        column: usize,
        /// Column name from the header.
        field: String,
        /// What is wrong with the value.
        msg: String,
    },
    /// The CSV parser failed (e.g. invalid UTF-8, unterminated quote).
    #[error("{}: line {line}: malformed CSV: {msg}", path.display())]
    Syntax {
        /// The CSV file.
        path: PathBuf,
        /// Line where parsing failed (0 if unknown).
        line: u64,
        /// The parser's message.
        msg: String,
    },
    /// A residue file parsed but does not form a valid residue series.
    #[error("{}: line {line}: {source}", path.display())]
    Series {
        /// The residue file.
        path: PathBuf,
        /// Line of the offending step (1 when the whole file is concerned).
        line: u64,
        /// The validation error.
        #[source]
        source: ResidueError,
    },
    /// Files of one flight directory disagree with each other.
    #[error("{}: {msg}", path.display())]
    Inconsistent {
        /// The file found inconsistent with the others.
        path: PathBuf,
        /// What disagrees.
        msg: String,
    },
    /// A value cannot be written (non-finite or otherwise unrepresentable).
    #[error("{}: cannot write row {row}, field `{field}`: {msg}", path.display())]
    Unwritable {
        /// The file being written.
        path: PathBuf,
        /// Index of the sample, 0-based.
        row: usize,
        /// Column name.
        field: String,
        /// What is wrong.
        msg: String,
    },
    /// A PX4 ULog cannot be read or lacks what a flight needs (naming the topic or field, and
    /// listing the topics the log has where one is missing).
    #[error("{}: {msg}", path.display())]
    Ulog {
        /// The log file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A TOML config could not be parsed or encoded.
    #[error("{}: {msg}", path.display())]
    Toml {
        /// The TOML file.
        path: PathBuf,
        /// The parser's message, which includes line and column.
        msg: String,
    },
}

/// Result alias of this module.
pub type Result<T, E = IoError> = std::result::Result<T, E>;
