//! Checkpoints of a fitted QUADFormer detector: safetensors weights plus a versioned JSON
//! manifest (config, channels, normaliser, scoring mode and threshold, every mode's validation
//! result, and the SHA-256 and size of the weights file).
//!
//! `save("run/qf.json")` writes `run/qf.json` and `run/qf.safetensors`, each to a temporary
//! file first and then renamed, so no partly written checkpoint is left behind. `load` checks,
//! in order: the manifest parses (unknown fields are errors), its format name and version, the
//! weights file's size and hash (truncation or corruption), the tensor names against the
//! network built from the config, and every shape (mismatch); each failure is a
//! [`ModelError::Checkpoint`] naming the file. A round trip gives bit-identical scores.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::detector::{ModeResult, QuadFormerConfig, QuadFormerDetector};
use crate::error::{ModelError, Result};
use crate::model::QuadFormerNet;
use crate::streaming::StreamingNet;
use crate::window::Normaliser;

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

fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

fn weights_path(manifest_path: &Path) -> PathBuf {
    manifest_path.with_extension("safetensors")
}

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(".tmp");
    path.with_file_name(name)
}

impl QuadFormerDetector {
    /// Saves the detector as `path` (JSON manifest) and `path` with extension `safetensors`.
    ///
    /// # Errors
    /// [`ModelError::Io`] or [`ModelError::Candle`] on write failure.
    pub fn save(&self, path: &Path) -> Result<()> {
        let weights = weights_path(path);
        let weights_tmp = tmp_path(&weights);
        self.net.varmap().save(&weights_tmp)?;
        let bytes = std::fs::read(&weights_tmp).map_err(io(&weights_tmp))?;
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            config: self.config.clone(),
            normaliser: self.norm.clone(),
            chosen: self.chosen,
            crit_scale: self.crit_scale,
            mode_results: self.mode_results.clone(),
            stream_threshold: Some(self.stream_threshold),
            weights_file: weights.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            weights_bytes: bytes.len() as u64,
            weights_sha256: sha256_hex(&bytes),
        };
        let json =
            serde_json::to_string_pretty(&manifest).map_err(|e| ck(path, format!("cannot serialise manifest: {e}")))?;
        let json_tmp = tmp_path(path);
        std::fs::write(&json_tmp, json).map_err(io(&json_tmp))?;
        std::fs::rename(&weights_tmp, &weights).map_err(io(&weights))?;
        std::fs::rename(&json_tmp, path).map_err(io(path))?;
        Ok(())
    }

    /// Loads a detector saved by [`QuadFormerDetector::save`] (checks in the module docs).
    ///
    /// # Errors
    /// [`ModelError::Io`] for a missing file; [`ModelError::Checkpoint`] naming the file for a
    /// malformed, truncated, corrupted or mismatched checkpoint.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(io(path))?;
        let manifest: Manifest = serde_json::from_str(&text)
            .map_err(|e| ck(path, format!("malformed manifest at line {}, column {}: {e}", e.line(), e.column())))?;
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
        let plain = Path::new(&manifest.weights_file).file_name().is_some_and(|n| n == manifest.weights_file.as_str());
        if !plain {
            return Err(ck(
                path,
                format!("weights_file must be a file name beside the manifest, got `{}`", manifest.weights_file),
            ));
        }
        let weights = path.with_file_name(&manifest.weights_file);
        let bytes = std::fs::read(&weights).map_err(io(&weights))?;
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
        if let Some(t) = manifest.stream_threshold
            && !t.is_finite()
        {
            return Err(ck(path, format!("stream_threshold must be finite, got {t}")));
        }
        let mut net = QuadFormerNet::new(&manifest.config.net, manifest.config.window.len, dim, 0)?;
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
            streaming: StreamingNet::new(&net)?,
            net,
            norm: manifest.normaliser,
            chosen: manifest.chosen,
            crit_scale: manifest.crit_scale,
            stream_threshold: manifest.stream_threshold.unwrap_or(manifest.chosen.threshold),
            mode_results: manifest.mode_results,
            report: None,
        })
    }
}
