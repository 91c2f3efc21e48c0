//! Checkpoints of a fitted QUADFormer detector: safetensors weights plus a versioned JSON
//! manifest (config, channels, normaliser, scoring mode and threshold, the streamed mode and
//! threshold, every mode's validation result, and the SHA-256 and size of the weights file).
//!
//! [`QuadFormerDetector::encode`] gives the manifest text and the weights bytes; the caller
//! writes them (eval writes `qf.json` and `qf.safetensors` atomically). `load` checks,
//! in order: the manifest parses (unknown fields are errors), its format name and version, the
//! configuration (every field, and the size budgets of window, widths, depths and batches),
//! `weights_file` is a plain file name beside the manifest, the weights file's size and hash
//! (truncation or corruption), the normaliser and the scoring results (finite thresholds, F1
//! in [0, 1], no mode twice), the tensor names against the network built from the config, and
//! every shape (mismatch); each failure is a [`ModelError::Checkpoint`] naming the file. A
//! round trip gives bit-identical scores.

use std::path::Path;

use candle_core::Device;
use serde::{Deserialize, Serialize};

use crate::detector::{ModeResult, QuadFormerConfig, QuadFormerDetector, ScoreMode};
use crate::error::{ModelError, Result};
use crate::model::QuadFormerNet;
use nn_toolkit::saved::{is_plain_name, malformed_json, sha256_hex};
use nn_toolkit::window::Normaliser;

/// Format name written into every manifest.
pub const FORMAT: &str = "quadformer-checkpoint";
/// Current manifest version.
pub const VERSION: u32 = 1;

/// The JSON manifest of a checkpoint (file format, versioned).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`VERSION`] when written.
    pub version: u32,
    /// Training configuration (architecture, window, losses, scoring).
    pub config: QuadFormerConfig,
    /// Normaliser fitted on the training split (also names the channels).
    pub normaliser: Normaliser,
    /// Scoring mode in use with its threshold.
    pub chosen: ModeResult,
    /// Median Anomaly Transformer criterion on validation (the combined mode's `a₅₀`).
    pub crit_scale: f64,
    /// Every mode's validation result.
    pub mode_results: Vec<ModeResult>,
    /// Threshold of the streaming detector, chosen on the validation split's streaming scores;
    /// a manifest without it streams at `chosen.threshold`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream_threshold: Option<f64>,
    /// Mode of the streaming detector, chosen with `stream_threshold`; a manifest without it
    /// streams `chosen.mode`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream_mode: Option<ScoreMode>,
    /// Validation F1 of the streaming detector's scores at `stream_threshold`; a manifest
    /// without it reports `chosen.valid_f1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream_f1: Option<f64>,
    /// File name of the weights, relative to the manifest.
    pub weights_file: String,
    /// Size of the weights file in bytes.
    pub weights_bytes: u64,
    /// Lower-case hex SHA-256 of the weights file.
    pub weights_sha256: String,
}

fn ck(path: &Path, msg: impl Into<String>) -> ModelError {
    ModelError::Checkpoint { path: path.to_path_buf(), msg: msg.into() }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ModelError + '_ {
    move |source| ModelError::Io { path: path.to_path_buf(), source }
}

/// Budget of a checkpoint manifest file.
pub const MAX_MANIFEST_BYTES: u64 = 16 << 20;
/// Budget of a weights file (about 250 M `f32` weights).
pub const MAX_WEIGHTS_BYTES: u64 = 1 << 30;

/// The bytes of regular file `path`, at most `max` of them (a longer file gives its first
/// `max` bytes, so the caller's size check reports it); devices and FIFOs are refused.
fn read_bounded_bytes(path: &Path, max: u64) -> Result<Vec<u8>> {
    use std::io::Read as _;
    let file = std::fs::File::open(path).map_err(io(path))?;
    let meta = file.metadata().map_err(io(path))?;
    if !meta.is_file() {
        return Err(ck(path, "not a regular file"));
    }
    let mut bytes = Vec::new();
    file.take(max).read_to_end(&mut bytes).map_err(io(path))?;
    Ok(bytes)
}

/// The text of regular file `path`, refused beyond `max` bytes.
fn read_bounded(path: &Path, max: u64) -> Result<String> {
    let bytes = read_bounded_bytes(path, max.saturating_add(1))?;
    if bytes.len() as u64 > max {
        return Err(ck(path, format!("more than the budget of {max} bytes for a manifest")));
    }
    String::from_utf8(bytes).map_err(|_| ck(path, "not UTF-8 text"))
}

/// Checks the manifest's numbers: thresholds and `crit_scale` finite, F1 values in [0, 1],
/// at most one result per mode and the chosen mode among them.
fn check_results(path: &Path, m: &Manifest) -> Result<()> {
    let finite = |field: &str, v: f64| {
        if v.is_finite() { Ok(()) } else { Err(ck(path, format!("{field} must be finite, got {v}"))) }
    };
    finite("chosen.threshold", m.chosen.threshold)?;
    finite("crit_scale", m.crit_scale)?;
    if let Some(t) = m.stream_threshold {
        finite("stream_threshold", t)?;
    }
    if let Some(f1) = m.stream_f1
        && !(0.0..=1.0).contains(&f1)
    {
        return Err(ck(path, format!("stream_f1 must be in [0, 1], got {f1}")));
    }
    let named = m.mode_results.iter().enumerate().map(|(i, r)| (format!("mode_results[{i}]"), r));
    for (field, r) in named.chain([("chosen".to_owned(), &m.chosen)]) {
        if r.threshold.is_nan() {
            return Err(ck(path, format!("{field}.threshold is NaN")));
        }
        if !(0.0..=1.0).contains(&r.valid_f1) {
            return Err(ck(path, format!("{field}.valid_f1 must be in [0, 1], got {}", r.valid_f1)));
        }
    }
    for (i, r) in m.mode_results.iter().enumerate() {
        if m.mode_results[..i].iter().any(|o| o.mode == r.mode) {
            return Err(ck(path, format!("mode_results lists {:?} twice", r.mode)));
        }
    }
    if !m.mode_results.is_empty() && !m.mode_results.iter().any(|r| r.mode == m.chosen.mode) {
        return Err(ck(path, format!("chosen mode {:?} is not among mode_results", m.chosen.mode)));
    }
    Ok(())
}

/// The two files of a checkpoint, encoded: the JSON manifest and the safetensors weights
/// it names. The caller writes them (`eval::io` writes every output atomically).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CheckpointFiles {
    /// Text of the JSON manifest.
    pub manifest: String,
    /// Bytes of the weights file.
    pub weights: Vec<u8>,
}

/// The weights file name beside manifest `manifest_name`: the same stem, `.safetensors`.
#[must_use]
pub fn weights_file_name(manifest_name: &str) -> String {
    Path::new(manifest_name).with_extension("safetensors").to_string_lossy().into_owned()
}

impl QuadFormerDetector {
    /// Encodes the detector as a checkpoint whose manifest names `weights_file` (a plain file
    /// name beside the manifest, [`weights_file_name`] of the manifest's name).
    ///
    /// # Errors
    /// [`ModelError::Checkpoint`] if `weights_file` is not a plain file name or encoding fails.
    pub fn encode(&self, weights_file: &str) -> Result<CheckpointFiles> {
        let here = Path::new(weights_file);
        if !is_plain_name(weights_file) {
            return Err(ck(here, "weights_file must be a plain file name"));
        }
        let weights = {
            let data = self
                .net
                .varmap()
                .data()
                .lock()
                .map_err(|_| ModelError::Data { msg: "variable map lock poisoned".into() })?;
            let tensors: Vec<(String, candle_core::Tensor)> =
                data.iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
            safetensors::tensor::serialize(tensors, None)
                .map_err(|e| ck(here, format!("cannot encode the weights: {e}")))?
        };
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            config: self.config.clone(),
            normaliser: self.norm.clone(),
            chosen: self.chosen,
            crit_scale: self.crit_scale,
            mode_results: self.mode_results.clone(),
            stream_threshold: Some(self.stream.threshold),
            stream_mode: Some(self.stream.mode),
            stream_f1: Some(self.stream.valid_f1),
            weights_file: weights_file.to_owned(),
            weights_bytes: weights.len() as u64,
            weights_sha256: sha256_hex(&weights),
        };
        let manifest = serde_json::to_string_pretty(&manifest)
            .map_err(|e| ck(here, format!("cannot serialise the manifest: {e}")))?;
        Ok(CheckpointFiles { manifest, weights })
    }

    /// Loads a detector from the files of [`QuadFormerDetector::encode`] (checks in the module
    /// docs) with its network on the CPU: [`QuadFormerDetector::load_on`] with
    /// [`Device::Cpu`].
    ///
    /// # Errors
    /// [`ModelError::Io`] for a missing file; [`ModelError::Checkpoint`] naming the file for a
    /// malformed, truncated, corrupted or mismatched checkpoint.
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_on(path, &Device::Cpu)
    }

    /// [`QuadFormerDetector::load`] with the network's variables on `device`.
    ///
    /// # Errors
    /// As [`QuadFormerDetector::load`].
    pub fn load_on(path: &Path, device: &Device) -> Result<Self> {
        let text = read_bounded(path, MAX_MANIFEST_BYTES)?;
        let manifest: Manifest = serde_json::from_str(&text).map_err(|e| ck(path, malformed_json("manifest", &e)))?;
        if manifest.format != FORMAT {
            return Err(ck(path, format!("format is `{}`, expected `{FORMAT}`", manifest.format)));
        }
        if manifest.version != VERSION {
            return Err(ck(
                path,
                format!("version {} is not supported (this build reads {VERSION})", manifest.version),
            ));
        }
        manifest.config.check()?;
        // The weights live beside the manifest: a plain file name, never a path.
        if !is_plain_name(&manifest.weights_file) {
            return Err(ck(
                path,
                format!("weights_file must be a file name beside the manifest, got `{}`", manifest.weights_file),
            ));
        }
        let weights = path.with_file_name(&manifest.weights_file);
        if manifest.weights_bytes > MAX_WEIGHTS_BYTES {
            return Err(ck(
                path,
                format!("weights_bytes {} exceeds the budget of {MAX_WEIGHTS_BYTES}", manifest.weights_bytes),
            ));
        }
        // Read at most one byte more than the manifest says: a longer file is "extended".
        let bytes = read_bounded_bytes(&weights, manifest.weights_bytes.saturating_add(1))?;
        if bytes.len() as u64 != manifest.weights_bytes {
            return Err(ck(
                &weights,
                format!("truncated or extended: {} bytes, manifest says {}", bytes.len(), manifest.weights_bytes),
            ));
        }
        if sha256_hex(&bytes) != manifest.weights_sha256 {
            return Err(ck(&weights, "corrupted: SHA-256 differs from the manifest"));
        }
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| ck(&weights, format!("not a safetensors file: {e}")))?;
        let dim = manifest.normaliser.dim();
        manifest.normaliser.check().map_err(|e| ck(path, e.to_string()))?;
        check_results(path, &manifest)?;
        let mut net = QuadFormerNet::new_on(&manifest.config.net, manifest.config.window.len, dim, 0, device)?;
        {
            let mut expected: Vec<String> = net
                .varmap()
                .data()
                .lock()
                .map_err(|_| ModelError::Data { msg: "variable map lock poisoned".into() })?
                .keys()
                .cloned()
                .collect();
            expected.sort();
            let mut found: Vec<String> = st.names().into_iter().map(str::to_owned).collect();
            found.sort();
            if expected != found {
                let missing: Vec<&String> = expected.iter().filter(|n| !found.contains(n)).collect();
                let extra: Vec<&String> = found.iter().filter(|n| !expected.contains(n)).collect();
                return Err(ck(
                    &weights,
                    format!("tensors do not match the config: missing {missing:?}, unexpected {extra:?}"),
                ));
            }
        }
        let mut vm = net.varmap().clone();
        vm.load(&weights).map_err(|e| ck(&weights, format!("does not match the config: {e}")))?;
        net.freeze()?;
        // The feature map the weights were trained on is the normaliser's; a configuration
        // saved before the field existed reads as `Raw` too, but the normaliser decides.
        let mut config = manifest.config;
        config.window.features = manifest.normaliser.features;
        Ok(QuadFormerDetector {
            config,
            streaming: crate::detector::streaming_engine(&net)?,
            net,
            norm: manifest.normaliser,
            chosen: manifest.chosen,
            crit_scale: manifest.crit_scale,
            stream: ModeResult {
                mode: manifest.stream_mode.unwrap_or(manifest.chosen.mode),
                smooth: 0,
                threshold: manifest.stream_threshold.unwrap_or(manifest.chosen.threshold),
                valid_f1: manifest.stream_f1.unwrap_or(manifest.chosen.valid_f1),
            },
            mode_results: manifest.mode_results,
            report: None,
        })
    }
}
