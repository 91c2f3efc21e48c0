//! Generic CSV machinery shared by every file format: a reader that resolves columns by header
//! name and parses fields with file/line/column errors, and a writer that prints `f64` in
//! Rust's shortest round-trip form (`{:?}`), so that write → read gives bit-identical values.
//!
//! Reading rules (docs/data-format.md, "General rules"): the first non-comment line is the
//! header; column order is free; extra columns are ignored unless a format forbids them;
//! surrounding spaces are trimmed; lines starting with `#` are comments; every record must have
//! as many fields as the header.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::io::error::{IoError, Result};

/// Renames of another tool's CSV columns to the project's (`THEIRS → OURS`), applied to every
/// header a flight read sees, so that its files need no rewriting (docs/data-format.md
/// "Another tool's CSV").
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ColumnMap(std::collections::BTreeMap<String, String>);

impl ColumnMap {
    /// Parses `THEIRS=OURS` pairs separated by commas (`gx=gyro_x,gy=gyro_y`).
    ///
    /// # Errors
    /// A message naming the pair that is not `THEIRS=OURS` or maps a name twice.
    pub fn parse_pairs(text: &str) -> std::result::Result<Self, String> {
        let mut map = std::collections::BTreeMap::new();
        for pair in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (theirs, ours) = pair
                .split_once('=')
                .map(|(a, b)| (a.trim(), b.trim()))
                .filter(|(a, b)| !a.is_empty() && !b.is_empty())
                .ok_or_else(|| format!("`{pair}` is not THEIRS=OURS"))?;
            if map.insert(theirs.to_owned(), ours.to_owned()).is_some() {
                return Err(format!("`{theirs}` is mapped twice"));
            }
        }
        Ok(Self(map))
    }

    /// Parses a TOML table of `THEIRS = "OURS"` strings (top level or under `[columns]`).
    ///
    /// # Errors
    /// A message naming the key whose value is not a string.
    pub fn parse_toml(text: &str) -> std::result::Result<Self, String> {
        let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| e.to_string())?;
        if let Some(toml::Value::Table(inner)) = table.get("columns") {
            if table.len() > 1 {
                return Err("a column map is either `[columns]` or top-level pairs, not both".into());
            }
            table = inner.clone();
        }
        let mut map = std::collections::BTreeMap::new();
        for (theirs, v) in table {
            let ours = v.as_str().ok_or_else(|| format!("`{theirs}`: the project's column name must be a string"))?;
            map.insert(theirs, ours.to_owned());
        }
        Ok(Self(map))
    }

    /// The project's name of a header name.
    fn rename<'a>(&'a self, name: &'a str) -> &'a str {
        self.0.get(name).map_or(name, String::as_str)
    }

    /// Whether the map renames nothing.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// An open CSV file with its header.
pub(crate) struct CsvIn {
    path: PathBuf,
    header: Vec<String>,
    header_line: u64,
    reader: csv::Reader<File>,
}

/// One record with the line it started on.
pub(crate) struct Row {
    line: u64,
    rec: csv::StringRecord,
}

impl Row {
    /// 1-based line number of the record.
    pub(crate) fn line(&self) -> u64 {
        self.line
    }
}

impl CsvIn {
    /// Opens `path` and reads its header.
    pub(crate) fn open(path: &Path) -> Result<Self> {
        Self::open_mapped(path, &ColumnMap::default())
    }

    /// Opens `path` and reads its header, renaming columns by `map`.
    pub(crate) fn open_mapped(path: &Path, map: &ColumnMap) -> Result<Self> {
        let file = crate::io::input_file::open_input(path, crate::io::input_file::MAX_CSV_BYTES)?;
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .from_reader(file);
        let mut rec = csv::StringRecord::new();
        let got = reader.read_record(&mut rec).map_err(|e| syntax(path, &e))?;
        if !got {
            return Err(IoError::Header { path: path.to_owned(), line: 1, msg: "empty file: no header line".into() });
        }
        let header_line = rec.position().map_or(1, csv::Position::line);
        // A UTF-8 byte-order mark (spreadsheet exports) is not part of the first name.
        let header: Vec<String> = rec
            .iter()
            .enumerate()
            .map(|(i, h)| map.rename(if i == 0 { h.trim_start_matches('\u{feff}') } else { h }).to_owned())
            .collect();
        for (i, name) in header.iter().enumerate() {
            if name.is_empty() {
                return Err(IoError::Header {
                    path: path.to_owned(),
                    line: header_line,
                    msg: format!("column {} has an empty name", i + 1),
                });
            }
            if header[..i].contains(name) {
                return Err(IoError::Header {
                    path: path.to_owned(),
                    line: header_line,
                    msg: format!("column `{name}` appears twice"),
                });
            }
        }
        Ok(Self { path: path.to_owned(), header, header_line, reader })
    }

    /// Header names in file order.
    pub(crate) fn header(&self) -> &[String] {
        &self.header
    }

    /// Line of the header.
    pub(crate) fn header_line(&self) -> u64 {
        self.header_line
    }

    /// Index of a required column.
    pub(crate) fn column(&self, name: &str) -> Result<usize> {
        self.optional_column(name).ok_or_else(|| IoError::MissingColumn {
            path: self.path.clone(),
            column: name.to_owned(),
            found: self.header.clone(),
        })
    }

    /// Index of an optional column.
    pub(crate) fn optional_column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// Indices of required columns, in the order asked; every missing one is named at once.
    pub(crate) fn columns(&self, names: &[&str]) -> Result<Vec<usize>> {
        let missing: Vec<String> =
            names.iter().filter(|n| self.optional_column(n).is_none()).map(|n| (*n).to_owned()).collect();
        match missing.len() {
            0 => names.iter().map(|n| self.column(n)).collect(),
            1 => Err(IoError::MissingColumn {
                path: self.path.clone(),
                column: missing[0].clone(),
                found: self.header.clone(),
            }),
            _ => Err(IoError::MissingColumns { path: self.path.clone(), columns: missing, found: self.header.clone() }),
        }
    }

    /// Reads the next record; `None` at the end of the file.
    pub(crate) fn next_row(&mut self) -> Result<Option<Row>> {
        let mut rec = csv::StringRecord::new();
        let got = self.reader.read_record(&mut rec).map_err(|e| syntax(&self.path, &e))?;
        if !got {
            return Ok(None);
        }
        let line = rec.position().map_or(0, csv::Position::line);
        if rec.len() != self.header.len() {
            return Err(IoError::FieldCount {
                path: self.path.clone(),
                line,
                expected: self.header.len(),
                found: rec.len(),
            });
        }
        Ok(Some(Row { line, rec }))
    }

    /// An error about field `col` of `row`.
    pub(crate) fn field_error(&self, row: &Row, col: usize, msg: impl Into<String>) -> IoError {
        IoError::Field {
            path: self.path.clone(),
            line: row.line,
            column: col + 1,
            field: self.header.get(col).cloned().unwrap_or_default(),
            msg: msg.into(),
        }
    }

    /// The raw text of field `col`.
    pub(crate) fn str<'r>(&self, row: &'r Row, col: usize) -> &'r str {
        row.rec.get(col).unwrap_or("")
    }

    /// Field `col` as a finite `f64`.
    pub(crate) fn f64(&self, row: &Row, col: usize) -> Result<f64> {
        let text = self.str(row, col);
        if text.is_empty() {
            return Err(self.field_error(row, col, "empty value"));
        }
        let v: f64 = text.parse().map_err(|_| self.field_error(row, col, format!("not a number: `{text}`")))?;
        if !v.is_finite() {
            return Err(self.field_error(row, col, format!("value `{text}` is not finite")));
        }
        Ok(v)
    }

    /// Fields `cols` as a finite 3-vector.
    pub(crate) fn vec3(&self, row: &Row, cols: &[usize]) -> Result<nalgebra::Vector3<f64>> {
        let mut v = nalgebra::Vector3::zeros();
        for (i, &c) in cols.iter().take(3).enumerate() {
            v[i] = self.f64(row, c)?;
        }
        Ok(v)
    }

    /// Fields `cols` as a 3-vector whose entries lie in `[-max, max]` (`unit` for messages):
    /// a plausibility bound that refuses corrupt or mis-scaled values.
    pub(crate) fn bounded_vec3(
        &self,
        row: &Row,
        cols: &[usize],
        max: f64,
        unit: &str,
    ) -> Result<nalgebra::Vector3<f64>> {
        let v = self.vec3(row, cols)?;
        for (i, &c) in cols.iter().take(3).enumerate() {
            if v[i].abs() > max {
                return Err(self.field_error(
                    row,
                    c,
                    format!("{:?} {unit} is outside the plausible range ±{max} {unit} (corrupt or mis-scaled?)", v[i]),
                ));
            }
        }
        Ok(v)
    }

    /// Field `col` as a non-negative integer that fits in `u32`.
    pub(crate) fn u32(&self, row: &Row, col: usize) -> Result<u32> {
        let text = self.str(row, col);
        text.parse().map_err(|_| self.field_error(row, col, format!("not a non-negative integer: `{text}`")))
    }

    /// Field `col` as a label: `0`/`1` (also `false`/`true`).
    pub(crate) fn label(&self, row: &Row, col: usize) -> Result<bool> {
        match self.str(row, col) {
            "0" | "false" => Ok(false),
            "1" | "true" => Ok(true),
            other => Err(self.field_error(row, col, format!("label must be 0 or 1, found `{other}`"))),
        }
    }

    /// Field `col` as a time stamp in seconds, strictly after `prev` (the previous record's).
    pub(crate) fn time(&self, row: &Row, col: usize, prev: Option<f64>) -> Result<f64> {
        let t = self.f64(row, col)?;
        if let Some(t_prev) = prev
            && t <= t_prev
        {
            return Err(self.field_error(
                row,
                col,
                format!("time stamps must increase strictly: {t:?} s is not after {t_prev:?} s"),
            ));
        }
        Ok(t)
    }
}

fn syntax(path: &Path, e: &csv::Error) -> IoError {
    let line = e.position().map_or(0, csv::Position::line);
    IoError::Syntax { path: path.to_owned(), line, msg: e.to_string() }
}

/// Builds CSV text row by row; values are checked finite and printed with `{:?}`
/// (shortest representation that parses back to the same `f64`).
pub(crate) struct CsvOut<'p> {
    path: &'p Path,
    header: Vec<String>,
    writer: BufWriter<File>,
    line: String,
    row: usize,
    col: usize,
}

impl<'p> CsvOut<'p> {
    /// Starts a file at `tmp` (the temporary file), reporting errors against `path` (the
    /// final name), and writes the header.
    pub(crate) fn new(path: &'p Path, tmp: File, header: Vec<String>) -> Result<Self> {
        let mut out =
            Self { path, header, writer: BufWriter::new(tmp), line: String::with_capacity(256), row: 0, col: 0 };
        out.line = out.header.join(",");
        out.line.push('\n');
        out.flush_line()?;
        Ok(out)
    }

    fn flush_line(&mut self) -> Result<()> {
        self.writer.write_all(self.line.as_bytes()).map_err(|source| IoError::Fs {
            path: self.path.to_owned(),
            op: "write",
            source,
        })?;
        self.line.clear();
        self.col = 0;
        Ok(())
    }

    fn sep(&mut self) {
        if self.col > 0 {
            self.line.push(',');
        }
        self.col += 1;
    }

    /// Appends one `f64` field.
    pub(crate) fn f64(&mut self, v: f64) -> Result<()> {
        if !v.is_finite() {
            return Err(IoError::Unwritable {
                path: self.path.to_owned(),
                row: self.row,
                field: self.header.get(self.col).cloned().unwrap_or_default(),
                msg: format!("non-finite value {v}"),
            });
        }
        self.sep();
        // `{:?}` is the shortest round-trip representation; writing to a String cannot fail.
        let _ = write!(self.line, "{v:?}");
        Ok(())
    }

    /// Appends three `f64` fields.
    pub(crate) fn vec3(&mut self, v: &nalgebra::Vector3<f64>) -> Result<()> {
        for x in v.iter() {
            self.f64(*x)?;
        }
        Ok(())
    }

    /// Appends one integer field.
    pub(crate) fn u64(&mut self, v: u64) {
        self.sep();
        let _ = write!(self.line, "{v}");
    }

    /// Appends a label as `0`/`1`.
    pub(crate) fn label(&mut self, v: bool) {
        self.u64(u64::from(v));
    }

    /// Ends the current row.
    pub(crate) fn end_row(&mut self) -> Result<()> {
        self.line.push('\n');
        self.flush_line()?;
        self.row += 1;
        Ok(())
    }

    /// Flushes and returns the file so the caller can sync and persist it.
    pub(crate) fn finish(self) -> Result<File> {
        let path = self.path.to_owned();
        self.writer.into_inner().map_err(|e| IoError::Fs { path, op: "write", source: e.into_error() })
    }
}
