//! Model directories (docs/decisions/081-model-directory-checkpoint-or-refit.md, amended by
//! docs/decisions/110-method-registry.md): what `quadformer train` writes and `quadformer
//! detect` and `quadformer fuse --model` load, for every method of the registry.
//!
//! Layout, written atomically ([`write()`]):
//! - `model.json` ([`ModelManifest`], format `quadformer-model-dir`, version 2): method,
//!   training channels, the threshold chosen on validation, seed, every method's configuration
//!   as used, the training files, and `state`, the files of the saved fitted state with their
//!   SHA-256;
//! - the state files, as the method's registry entry saves them ([`crate::methods`]):
//!   `detector.json` for the statistical methods and the SVM (their fitted parameters);
//!   `detector.json` + `detector.safetensors` for the CNN and LSTM (manifest with config,
//!   channels, normaliser and thresholds; weights); `quadformer.json` +
//!   `quadformer.safetensors` for QUADFormer (its checkpoint).
//!
//! Loading ([`load`]) never fits: it checks each state file's SHA-256 against `model.json`
//! before the method decodes it. A version-1 QUADFormer directory (storage `checkpoint`) still
//! loads; a version-1 directory that holds a copy of the training data (storage `refit`) is an
//! error naming `model.json` and saying to re-run `quadformer train`.

use std::io::Read as _;
use std::path::{Path, PathBuf};

use ekf_residue::Detector;
use serde::{Deserialize, Serialize};

use crate::io::{IoError, Overwrite, write_bytes_atomic, write_dir_atomic, write_text_atomic};
use crate::methods::{Method, MethodConfigs};

/// Name of the model manifest in a model directory.
pub const MODEL_FILE: &str = "model.json";
/// Format name written into every model manifest.
pub const MODEL_FORMAT: &str = "quadformer-model-dir";
/// Current model manifest version.
pub const MODEL_VERSION: u32 = 2;
/// Most files a model manifest may list (training plus validation flights).
pub const MAX_MANIFEST_FILES: usize = 100_000;
/// Largest state file read, bytes.
pub const MAX_STATE_BYTES: u64 = 1 << 31;

/// A model directory could not be written or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelDirError {
    /// Reading or writing a file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A file of the directory is malformed, corrupt or inconsistent.
    #[error("{}: {msg}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the field.
        msg: String,
    },
}

/// Result alias of this module.
pub type Result<T, E = ModelDirError> = std::result::Result<T, E>;

/// One file of a saved fitted state: a plain file name in the model directory and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StateFile {
    /// Plain file name.
    pub name: String,
    /// Contents.
    pub bytes: Vec<u8>,
}

impl StateFile {
    /// A state file of text.
    #[must_use]
    pub fn text(name: &str, text: String) -> Self {
        Self { name: name.to_owned(), bytes: text.into_bytes() }
    }
}

/// One state file as `model.json` lists it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateEntry {
    /// Plain file name in the model directory.
    pub file: String,
    /// Lower-case hex SHA-256 of the file, checked before it is read (absent only in
    /// version-1 QUADFormer directories written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
}

/// The `model.json` manifest of a model directory (file format, versioned).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelManifest {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// [`MODEL_VERSION`] when written.
    pub version: u32,
    /// The method.
    pub method: Method,
    /// Residue channels the method was trained on, in order.
    pub channels: Vec<String>,
    /// Alarm threshold chosen on validation (a step alarms when its score exceeds it).
    pub threshold: f64,
    /// Seed of the method's random parts (weights, shuffling, subsampling).
    pub seed: u64,
    /// Every method's configuration as used (already seeded).
    pub configs: MethodConfigs,
    /// The files of the saved fitted state.
    pub state: Vec<StateEntry>,
    /// Training and validation flight files the model was fitted on (as given).
    pub trained_on: Vec<String>,
}

pub use nn_toolkit::saved::sha256_hex;

pub use nn_toolkit::saved::is_plain_name;

/// What a fitted method's model directory records besides its state.
#[derive(Debug, Clone, PartialEq)]
pub struct Trained {
    /// The method.
    pub method: Method,
    /// Training channels.
    pub channels: Vec<String>,
    /// Threshold chosen on validation.
    pub threshold: f64,
    /// Seed.
    pub seed: u64,
    /// Configurations as used.
    pub configs: MethodConfigs,
    /// Training and validation files.
    pub trained_on: Vec<String>,
}

/// Writes a model directory atomically: the state files and `model.json` listing them.
///
/// # Errors
/// [`ModelDirError::Invalid`] for a state file name that is not plain or repeated; I/O errors
/// naming the file.
pub fn write(out: &Path, overwrite: Overwrite, trained: Trained, files: &[StateFile]) -> Result<ModelManifest> {
    let manifest_path = out.join(MODEL_FILE);
    for (i, f) in files.iter().enumerate() {
        if !is_plain_name(&f.name) || f.name == MODEL_FILE || files[..i].iter().any(|g| g.name == f.name) {
            return Err(ModelDirError::Invalid {
                path: manifest_path,
                msg: format!("state file `{}` is not a plain, distinct file name", f.name),
            });
        }
    }
    let manifest = ModelManifest {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        method: trained.method,
        channels: trained.channels,
        threshold: trained.threshold,
        seed: trained.seed,
        configs: trained.configs,
        state: files.iter().map(|f| StateEntry { file: f.name.clone(), sha256: Some(sha256_hex(&f.bytes)) }).collect(),
        trained_on: trained.trained_on,
    };
    let json = serde_json::to_string_pretty(&manifest)
        .map_err(|e| ModelDirError::Invalid { path: manifest_path.clone(), msg: format!("cannot serialise: {e}") })?;
    write_dir_atomic(out, overwrite, |dir| -> Result<()> {
        for f in files {
            write_bytes_atomic(&dir.join(&f.name), &f.bytes)?;
        }
        write_text_atomic(&dir.join(MODEL_FILE), &json)?;
        Ok(())
    })?;
    Ok(manifest)
}

/// The saved state of a model directory, as a method's entry reads it: each file is checked
/// against its SHA-256 in `model.json` when read.
#[derive(Debug, Clone, Copy)]
pub struct SavedState<'a> {
    dir: &'a Path,
    entries: &'a [StateEntry],
}

impl<'a> SavedState<'a> {
    /// The state listed by `manifest` in `dir`.
    #[must_use]
    pub fn new(dir: &'a Path, manifest: &'a ModelManifest) -> Self {
        Self { dir, entries: &manifest.state }
    }

    /// The path of state file `name`, after checking that `model.json` lists it and that its
    /// contents match the recorded SHA-256 (for decoders that read files by path).
    ///
    /// # Errors
    /// As [`SavedState::read`].
    pub fn checked_path(&self, name: &str) -> Result<PathBuf> {
        self.read(name)?;
        Ok(self.dir.join(name))
    }

    /// The path of state file `name` (for error messages).
    #[must_use]
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// The bytes of state file `name`.
    ///
    /// # Errors
    /// [`ModelDirError::Invalid`] naming `model.json` when it does not list the file, or the
    /// file when it is larger than [`MAX_STATE_BYTES`] or its SHA-256 differs; I/O errors.
    pub fn read(&self, name: &str) -> Result<Vec<u8>> {
        let Some(entry) = self.entries.iter().find(|e| e.file == name) else {
            return Err(ModelDirError::Invalid {
                path: self.dir.join(MODEL_FILE),
                msg: format!("state: no file `{name}`; was the directory written by another method?"),
            });
        };
        let path = self.dir.join(name);
        let fs = |source| IoError::Fs { path: path.clone(), op: "read", source };
        // A regular file within the budget (a device or FIFO is refused before reading).
        let file = crate::io::open_input(&path, MAX_STATE_BYTES)?;
        let mut bytes = Vec::new();
        file.take(MAX_STATE_BYTES + 1).read_to_end(&mut bytes).map_err(fs)?;
        if bytes.len() as u64 > MAX_STATE_BYTES {
            return Err(ModelDirError::Invalid {
                path,
                msg: format!("larger than the budget of {MAX_STATE_BYTES} bytes"),
            });
        }
        if let Some(want) = &entry.sha256
            && sha256_hex(&bytes) != *want
        {
            return Err(ModelDirError::Invalid {
                path,
                msg: format!("corrupted: SHA-256 differs from the one in {MODEL_FILE}"),
            });
        }
        Ok(bytes)
    }

    /// The text of state file `name`.
    ///
    /// # Errors
    /// As [`SavedState::read`]; [`ModelDirError::Invalid`] when it is not UTF-8.
    pub fn read_text(&self, name: &str) -> Result<String> {
        String::from_utf8(self.read(name)?)
            .map_err(|_| ModelDirError::Invalid { path: self.path(name), msg: "not UTF-8 text".into() })
    }
}

/// Checks every field of a parsed manifest (see [`read_manifest`]); the message names the field.
fn check_fields(m: &ModelManifest) -> std::result::Result<(), String> {
    if m.channels.is_empty() {
        return Err("channels: empty".into());
    }
    if m.channels.len() > nn_toolkit::window::MAX_CHANNELS {
        return Err(format!(
            "channels: {} exceed the budget of {}",
            m.channels.len(),
            nn_toolkit::window::MAX_CHANNELS
        ));
    }
    for (i, c) in m.channels.iter().enumerate() {
        if c.is_empty() || c.chars().any(|ch| ch.is_control() || ch == ',') {
            return Err(format!("channels[{i}]: {c:?} is not a channel name (empty, a control character or `,`)"));
        }
        if m.channels[..i].contains(c) {
            return Err(format!("channels[{i}]: `{c}` is listed twice"));
        }
    }
    if !m.threshold.is_finite() {
        return Err(format!("threshold: must be finite, got {}", m.threshold));
    }
    if m.trained_on.len() > MAX_MANIFEST_FILES {
        return Err(format!("trained_on: {} entries exceed the budget of {MAX_MANIFEST_FILES}", m.trained_on.len()));
    }
    if m.state.is_empty() {
        return Err("state: no files".into());
    }
    for (i, e) in m.state.iter().enumerate() {
        if !is_plain_name(&e.file) || e.file == MODEL_FILE {
            return Err(format!("state[{i}].file: `{}` must be a plain file name in the model directory", e.file));
        }
        if m.state[..i].iter().any(|o| o.file == e.file) {
            return Err(format!("state[{i}].file: `{}` is listed twice", e.file));
        }
        match &e.sha256 {
            Some(h) if h.len() == 64 && h.chars().all(|c| c.is_ascii_digit() || ('a'..='f').contains(&c)) => {}
            Some(h) => return Err(format!("state[{i}].sha256: `{h}` is not a lower-case hex SHA-256")),
            None if m.version >= 2 => return Err(format!("state[{i}].sha256: missing")),
            None => {}
        }
    }
    Ok(())
}

/// The format name and version of a manifest, read first so that another version gives a
/// version error, not a field error.
#[derive(Deserialize)]
struct Header {
    format: String,
    version: u32,
}

/// Version 1 of `model.json`, read for its QUADFormer checkpoints.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestV1 {
    format: String,
    version: u32,
    #[serde(deserialize_with = "method_v1")]
    method: Method,
    channels: Vec<String>,
    threshold: f64,
    seed: u64,
    configs: MethodConfigs,
    storage: StorageV1,
    trained_on: Vec<String>,
}

/// A method as version 1 wrote it: the slug, except `quad-former` for QUADFormer.
fn method_v1<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Method, D::Error> {
    let s = String::deserialize(d)?;
    if s == "quad-former" {
        return Ok(Method::QuadFormer);
    }
    s.parse().map_err(serde::de::Error::custom)
}

/// How version 1 kept the fitted detector.
#[derive(Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind", deny_unknown_fields)]
enum StorageV1 {
    /// A QUADFormer checkpoint.
    Checkpoint {
        manifest: String,
        #[serde(default)]
        manifest_sha256: Option<String>,
    },
    /// A copy of the training data, re-fitted at every `detect`: no longer read.
    #[allow(dead_code)]
    Refit { train: Vec<String>, valid: Vec<String> },
}

/// Reads and checks the `model.json` of a model directory.
///
/// # Errors
/// I/O errors if it cannot be read; [`ModelDirError::Invalid`] naming the file when it is
/// malformed (line and column), of another format or version, holds copied training data
/// instead of a saved state (version 1 `refit`: re-run `quadformer train`), or a field is
/// invalid (named): no channels or a duplicate, a threshold that is not finite, a state file
/// that is not a plain name inside the model directory, a list over its budget.
pub fn read_manifest(model_dir: &Path) -> Result<ModelManifest> {
    let path = model_dir.join(MODEL_FILE);
    let bad = |msg: String| ModelDirError::Invalid { path: path.clone(), msg };
    let text = crate::io::read_text(&path)?;
    let malformed = |e: serde_json::Error| bad(nn_toolkit::saved::malformed_json("model manifest", &e));
    let h: Header = serde_json::from_str(&text).map_err(malformed)?;
    if h.format != MODEL_FORMAT {
        return Err(bad(format!("format is `{}`, expected `{MODEL_FORMAT}`", h.format)));
    }
    let m = match h.version {
        MODEL_VERSION => serde_json::from_str::<ModelManifest>(&text).map_err(malformed)?,
        1 => {
            let v1: ManifestV1 = serde_json::from_str(&text).map_err(malformed)?;
            let state = match v1.storage {
                StorageV1::Checkpoint { manifest, .. }
                    if v1.method == Method::QuadFormer && manifest != crate::methods::CHECKPOINT_FILE =>
                {
                    return Err(bad(format!(
                        "storage.manifest: `{manifest}`, this build reads the checkpoint `{}`",
                        crate::methods::CHECKPOINT_FILE
                    )));
                }
                StorageV1::Checkpoint { manifest, manifest_sha256 } if v1.method == Method::QuadFormer => {
                    let weights = quadformer_model::checkpoint::weights_file_name(&manifest);
                    // The checkpoint manifest carries the size and SHA-256 of its weights.
                    vec![
                        StateEntry { file: manifest, sha256: manifest_sha256 },
                        StateEntry { file: weights, sha256: None },
                    ]
                }
                StorageV1::Checkpoint { .. } => {
                    return Err(bad(format!("{} cannot be stored as a QUADFormer checkpoint", v1.method.name())));
                }
                StorageV1::Refit { .. } => {
                    return Err(bad(format!(
                        "holds a copy of the training data (`storage.kind = \"refit\"`, directory `data/`) instead of \
                         a saved {} state; re-run `quadformer train` to write a model directory this build loads",
                        v1.method.name()
                    )));
                }
            };
            ModelManifest {
                format: v1.format,
                version: v1.version,
                method: v1.method,
                channels: v1.channels,
                threshold: v1.threshold,
                seed: v1.seed,
                configs: v1.configs,
                state,
                trained_on: v1.trained_on,
            }
        }
        v => return Err(bad(format!("version {v} is not supported (this build reads 1 and {MODEL_VERSION})"))),
    };
    check_fields(&m).map_err(bad)?;
    Ok(m)
}

/// Loads the fitted detector of a model directory whose manifest is `m` (never fits); the
/// decoded detector must read the manifest's channels and alarm above its threshold.
///
/// # Errors
/// As [`SavedState::read`] and the method's decoder, naming the file;
/// [`ModelDirError::Invalid`] naming `model.json` when the state disagrees with it.
pub fn load(model_dir: &Path, m: &ModelManifest) -> Result<Box<dyn Detector>> {
    let det = m.method.load(&SavedState::new(model_dir, m))?;
    let bad = |msg: String| ModelDirError::Invalid { path: model_dir.join(MODEL_FILE), msg };
    if det.channels() != m.channels.as_slice() {
        return Err(bad(format!("channels: {:?}, but the saved state reads {:?}", m.channels, det.channels())));
    }
    if det.threshold().to_bits() != m.threshold.to_bits() {
        return Err(bad(format!("threshold: {}, but the saved state alarms above {}", m.threshold, det.threshold())));
    }
    Ok(det)
}
