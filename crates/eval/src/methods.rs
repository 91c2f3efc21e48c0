//! The registry of detection methods: one entry per method of Tables I and II (the paper's
//! seven rows, tab:comprehensive_analysis1 and tab:comprehensive_analysis2, plus two extra
//! rows), in table order (docs/decisions/110-method-registry.md).
//!
//! An entry is one [`MethodSpec`] implementation on the method's configuration type, written
//! inside the `registry!` invocation below: its command-line name, table name and row group,
//! its configuration field, the `--quick` and seeded variants of that configuration, its
//! window, and how its fitted state is saved and loaded. The macro derives from the list
//! the [`Method`] enum, [`Method::ALL`], the [`MethodConfigs`] struct (one field per method:
//! the `[<field>]` table of a `train --config` file, `[methods.<field>]` in a
//! `reproduce-tables --config` file) and every dispatch from a [`Method`] to its
//! entry, so adding a detector is adding one entry.

use baselines::JsonState;
use ekf_residue::{Detector, Fit, LabelledResidues};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use baselines::{
    BhtConfig, Chi2Config, CnnConfig, CusumConfig, GlrConfig, LstmConfig, Px4GateConfig, SprtConfig, SvmConfig,
};
use nn_toolkit::WindowConfig;
use quadformer_model::{QuadFormerConfig, QuadFormerDetector};

use crate::model_dir::{ModelDirError, SavedState, StateFile};

/// The row group of a method in Tables I and II.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MethodGroup {
    /// Residue-based statistical tests of the paper: CUSUM, SPRT, BHT.
    Traditional,
    /// Learning-based baselines of the paper: SVM, CNN, LSTM.
    LearningBased,
    /// QUADFormer.
    Ours,
    /// Methods that are not rows of the paper (chi-squared, PX4-style gate, GLR drift test).
    Extra,
}

impl MethodGroup {
    /// Row label in the Markdown tables.
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Traditional => "Traditional",
            Self::LearningBased => "Learning-based",
            Self::Ours => "Ours",
            Self::Extra => "Extra (not in the paper)",
        }
    }

    /// Row label in the LaTeX tables.
    #[must_use]
    pub fn latex_label(self) -> &'static str {
        match self {
            Self::Traditional => "Traditional Method",
            Self::LearningBased => "\\parbox{2cm}{\\centering Learning-based\\\\ Method}",
            Self::Ours => "\\textbf{Ours}",
            Self::Extra => "\\parbox{2cm}{\\centering Extra (not in\\\\ the paper)}",
        }
    }
}

/// An unknown method name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown method `{0}` (known: {known})", known = known_slugs())]
pub struct UnknownMethod(pub String);

fn known_slugs() -> String {
    Method::ALL.iter().map(|m| m.slug()).collect::<Vec<_>>().join(", ")
}

/// One method of the registry: everything about it that is not its fitting ([`Fit`]) or its
/// scoring ([`Detector`]), on its configuration type.
pub trait MethodSpec:
    Fit<Detector: Detector + 'static, Error: std::fmt::Display>
    + Serialize
    + DeserializeOwned
    + Clone
    + Send
    + Sync
    + 'static
{
    /// Command-line and file-name form, e.g. `px4-gate`.
    const SLUG: &'static str;
    /// Table name (what the fitted detector's `Detector::name` returns under the default tuning;
    /// a textbook-tuned variant names its tuning too, but its rows carry this name).
    const NAME: &'static str;
    /// Row group in Tables I and II.
    const GROUP: MethodGroup;
    /// Whether the method learns from labelled windows (and so depends on the seed beyond the
    /// data, and has streaming metrics).
    const LEARNING: bool = false;
    /// Whether the method needs the GPS innovation channels (it does not apply to the VO-only
    /// Model II cells).
    const NEEDS_GPS: bool = false;

    /// Window length of a windowed method.
    fn window_len(&self) -> Option<usize> {
        None
    }

    /// Switches off per-epoch progress bars (the full run shows its own).
    fn quiet(&mut self) {}

    /// The `--quick` variant: small networks and few epochs.
    fn quick(&mut self) {}

    /// Seeds the random parts (weights, shuffling, subsampling).
    fn seed(&mut self, _seed: u64) {}

    /// Checks sizes against their budgets before any data is read.
    ///
    /// # Errors
    /// The first bad field, as text.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }

    /// Encodes the fitted state as files of a model directory
    /// ([`crate::model_dir`]).
    ///
    /// # Errors
    /// The encoder's error, as text.
    fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String>;

    /// Decodes the fitted state saved by [`MethodSpec::save`].
    ///
    /// # Errors
    /// [`ModelDirError`] naming the file that is missing, malformed, corrupt or inconsistent.
    fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError>;
}

/// An operation generic over the configuration type of one method ([`Method::visit`]).
pub trait Visit {
    /// What the operation returns.
    type Output;
    /// Applies the operation to the method whose configuration is `cfg`.
    fn visit<S: MethodSpec>(self, cfg: &S) -> Self::Output;
}

/// An operation that changes every method's configuration ([`MethodConfigs::visit_all_mut`]).
pub trait VisitMut {
    /// Applies the operation to one method's configuration.
    fn visit<S: MethodSpec>(&mut self, cfg: &mut S);
}

/// Defines [`Method`], [`MethodConfigs`] and the dispatch between them from one list of
/// entries `Variant(field: ConfigType) { MethodSpec items }`, in table order.
macro_rules! registry {
    ($( $(#[$doc:meta])* $variant:ident($field:ident: $config:ty) { $($spec:tt)* } )*) => {
        /// A detection method of the comparison, in table order ([`Method::ALL`]).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub enum Method {
            $( $(#[$doc])* $variant, )*
        }

        impl Method {
            /// Every method, in table order.
            pub const ALL: &'static [Method] = &[$(Method::$variant),*];

            /// The command-line and file-name form, e.g. `px4-gate`.
            #[must_use]
            pub const fn slug(self) -> &'static str {
                match self { $( Method::$variant => <$config as MethodSpec>::SLUG, )* }
            }

            /// The name used in tables (as the fitted detector's `Detector::name` returns it).
            #[must_use]
            pub const fn name(self) -> &'static str {
                match self { $( Method::$variant => <$config as MethodSpec>::NAME, )* }
            }

            /// The row group in Tables I and II.
            #[must_use]
            pub const fn group(self) -> MethodGroup {
                match self { $( Method::$variant => <$config as MethodSpec>::GROUP, )* }
            }

            /// The method's field in [`MethodConfigs`]: its table in a TOML configuration.
            #[must_use]
            pub const fn config_key(self) -> &'static str {
                match self { $( Method::$variant => stringify!($field), )* }
            }

            /// Whether the method learns from labelled windows.
            #[must_use]
            pub const fn is_learning(self) -> bool {
                match self { $( Method::$variant => <$config as MethodSpec>::LEARNING, )* }
            }

            /// Whether the method needs the GPS innovation channels.
            #[must_use]
            pub const fn needs_gps(self) -> bool {
                match self { $( Method::$variant => <$config as MethodSpec>::NEEDS_GPS, )* }
            }

            /// Applies `op` to this method's configuration in `cfgs`.
            pub fn visit<V: Visit>(self, cfgs: &MethodConfigs, op: V) -> V::Output {
                match self { $( Method::$variant => op.visit(&cfgs.$field), )* }
            }
        }

        /// The hyper-parameters of every method, one field per registry entry. Defaults are
        /// each method's own documented defaults.
        #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
        #[serde(deny_unknown_fields, default)]
        pub struct MethodConfigs {
            $( $(#[$doc])* pub $field: $config, )*
        }

        impl MethodConfigs {
            /// Applies `op` to every method's configuration, in table order.
            pub fn visit_all_mut<V: VisitMut>(&mut self, op: &mut V) {
                $( op.visit(&mut self.$field); )*
            }
        }

        $( impl MethodSpec for $config { $($spec)* } )*
    };
}

/// Width of the `--quick` windows, shared by QUADFormer, CNN and LSTM. They read the
/// per-step features (`WhitenedLog`): on the quick cell's five training flights the tiny
/// QUADFormer does not learn the drift channel (docs/decisions/094-drift-channel.md).
const QUICK_WINDOW_LEN: usize = 50;

/// The `--quick` window of the networks: QUADFormer's tiny configuration's.
fn quick_window() -> WindowConfig {
    QuadFormerConfig::tiny(QUICK_WINDOW_LEN).window
}

/// The `--quick` variant of the CNN and LSTM configurations.
fn quick_neural(nn: &mut baselines::NeuralConfig) {
    nn.window = quick_window();
    nn.score_stride = 25;
    nn.hidden = 16;
    nn.train.epochs = 2;
    nn.train.max_windows_per_epoch = Some(256);
    nn.train.progress = false;
}

/// Seeds the weights and the training loop of the CNN and LSTM.
fn seed_neural(nn: &mut baselines::NeuralConfig, seed: u64) {
    nn.seed = seed;
    nn.train.seed = seed;
}

/// The state file of a detector saved as JSON of its fitted parameters.
pub const JSON_STATE_FILE: &str = "detector.json";
/// The weights of a saved CNN or LSTM, beside its [`JSON_STATE_FILE`] manifest.
pub const NEURAL_WEIGHTS_FILE: &str = "detector.safetensors";
/// The manifest of a saved QUADFormer checkpoint (weights beside it, `.safetensors`).
pub const CHECKPOINT_FILE: &str = "quadformer.json";

/// Saves a detector as JSON of its fitted parameters.
fn save_json<D: JsonState>(det: &D) -> Result<Vec<StateFile>, String> {
    Ok(vec![StateFile::text(JSON_STATE_FILE, det.to_json().map_err(|e| e.to_string())?)])
}

/// Loads a detector saved by [`save_json`].
fn load_json<D: JsonState>(state: &SavedState<'_>) -> Result<D, ModelDirError> {
    let text = state.read_text(JSON_STATE_FILE)?;
    D::from_json(&text).map_err(|e| ModelDirError::Invalid { path: state.path(JSON_STATE_FILE), msg: e.to_string() })
}

/// Saves a CNN or LSTM: manifest and weights.
fn save_neural<N: baselines::nn::PerStepNet>(det: &baselines::nn::NeuralDetector<N>) -> Result<Vec<StateFile>, String> {
    let files = det.encode().map_err(|e| e.to_string())?;
    Ok(vec![
        StateFile::text(JSON_STATE_FILE, files.manifest),
        StateFile { name: NEURAL_WEIGHTS_FILE.into(), bytes: files.weights },
    ])
}

/// Loads a CNN or LSTM saved by [`save_neural`] with `decode`.
fn load_neural<D>(
    state: &SavedState<'_>,
    decode: impl FnOnce(&str, &[u8]) -> baselines::Result<D>,
) -> Result<D, ModelDirError> {
    let manifest = state.read_text(JSON_STATE_FILE)?;
    let weights = state.read(NEURAL_WEIGHTS_FILE)?;
    decode(&manifest, &weights)
        .map_err(|e| ModelDirError::Invalid { path: state.path(JSON_STATE_FILE), msg: e.to_string() })
}

registry! {
    /// CUSUM on the NIS (Murguia & Ruths).
    Cusum(cusum: CusumConfig) {
        const SLUG: &'static str = "cusum";
        const NAME: &'static str = "CUSUM";
        const GROUP: MethodGroup = MethodGroup::Traditional;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// Wald's sequential probability ratio test.
    Sprt(sprt: SprtConfig) {
        const SLUG: &'static str = "sprt";
        const NAME: &'static str = "SPRT";
        const GROUP: MethodGroup = MethodGroup::Traditional;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// Binary hypothesis test (ellipsoid).
    Bht(bht: BhtConfig) {
        const SLUG: &'static str = "bht";
        const NAME: &'static str = "BHT";
        const GROUP: MethodGroup = MethodGroup::Traditional;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// RBF support vector machine on residue windows.
    Svm(svm: SvmConfig) {
        const SLUG: &'static str = "svm";
        const NAME: &'static str = "SVM";
        const GROUP: MethodGroup = MethodGroup::LearningBased;
        const LEARNING: bool = true;

        fn window_len(&self) -> Option<usize> {
            Some(self.window)
        }

        fn quick(&mut self) {
            self.max_train = 400;
            self.c_grid = vec![1.0];
            self.gamma_grid = vec![1.0];
        }

        fn seed(&mut self, seed: u64) {
            self.seed = seed;
        }

        fn check(&self) -> Result<(), String> {
            SvmConfig::check(self).map_err(|e| e.to_string())
        }

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// 1-D convolutional network on residue windows.
    Cnn(cnn: CnnConfig) {
        const SLUG: &'static str = "cnn";
        const NAME: &'static str = "CNN";
        const GROUP: MethodGroup = MethodGroup::LearningBased;
        const LEARNING: bool = true;

        fn window_len(&self) -> Option<usize> {
            Some(self.0.window.len)
        }

        fn quiet(&mut self) {
            self.0.train.progress = false;
        }

        fn quick(&mut self) {
            quick_neural(&mut self.0);
        }

        fn seed(&mut self, seed: u64) {
            seed_neural(&mut self.0, seed);
        }

        fn check(&self) -> Result<(), String> {
            self.0.check().map_err(|e| e.to_string())
        }

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_neural(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_neural(state, baselines::Cnn::decode)
        }
    }

    /// LSTM on residue windows.
    Lstm(lstm: LstmConfig) {
        const SLUG: &'static str = "lstm";
        const NAME: &'static str = "LSTM";
        const GROUP: MethodGroup = MethodGroup::LearningBased;
        const LEARNING: bool = true;

        fn window_len(&self) -> Option<usize> {
            Some(self.0.window.len)
        }

        fn quiet(&mut self) {
            self.0.train.progress = false;
        }

        fn quick(&mut self) {
            quick_neural(&mut self.0);
        }

        fn seed(&mut self, seed: u64) {
            seed_neural(&mut self.0, seed);
        }

        fn check(&self) -> Result<(), String> {
            self.0.check().map_err(|e| e.to_string())
        }

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_neural(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_neural(state, baselines::Lstm::decode)
        }
    }

    /// QUADFormer (paper sec:attack_detector).
    QuadFormer(quadformer: QuadFormerConfig) {
        const SLUG: &'static str = "quadformer";
        const NAME: &'static str = "QUADFormer";
        const GROUP: MethodGroup = MethodGroup::Ours;
        const LEARNING: bool = true;

        fn window_len(&self) -> Option<usize> {
            Some(self.window.len)
        }

        fn quiet(&mut self) {
            self.train.progress = false;
        }

        fn quick(&mut self) {
            *self = QuadFormerConfig::tiny(QUICK_WINDOW_LEN);
            self.train.epochs = 2;
            self.train.max_windows_per_epoch = Some(256);
            self.train.labelled_share = Some(0.5);
            self.train.mirror = true;
            self.train.mix = 0.5;
        }

        fn seed(&mut self, seed: u64) {
            self.train.seed = seed;
        }

        fn check(&self) -> Result<(), String> {
            QuadFormerConfig::check(self).map_err(|e| e.to_string())
        }

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            let weights = quadformer_model::checkpoint::weights_file_name(CHECKPOINT_FILE);
            let files = det.encode(&weights).map_err(|e| e.to_string())?;
            Ok(vec![StateFile::text(CHECKPOINT_FILE, files.manifest), StateFile { name: weights, bytes: files.weights }])
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            let manifest = state.checked_path(CHECKPOINT_FILE)?;
            let weights = quadformer_model::checkpoint::weights_file_name(CHECKPOINT_FILE);
            state.checked_path(&weights)?;
            // Checkpoint errors name their own file.
            QuadFormerDetector::load(&manifest).map_err(|e| match e {
                quadformer_model::ModelError::Checkpoint { path, msg } => ModelDirError::Invalid { path, msg },
                quadformer_model::ModelError::Io { path, source } => {
                    ModelDirError::Io(crate::io::IoError::Fs { path, op: "read", source })
                }
                other => ModelDirError::Invalid {
                    path: manifest.clone(),
                    msg: format!("cannot load the QUADFormer checkpoint: {other}"),
                },
            })
        }
    }

    /// Chi-squared test on the NIS (extra row).
    Chi2(chi2: Chi2Config) {
        const SLUG: &'static str = "chi2";
        const NAME: &'static str = "Chi2";
        const GROUP: MethodGroup = MethodGroup::Extra;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// PX4 EKF2-style GPS innovation gate (extra row).
    Px4Gate(px4_gate: Px4GateConfig) {
        const SLUG: &'static str = "px4-gate";
        const NAME: &'static str = "PX4 gate";
        const GROUP: MethodGroup = MethodGroup::Extra;
        const NEEDS_GPS: bool = true;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }

    /// GLR drift test on the GPS innovation (extra row).
    Glr(glr: GlrConfig) {
        const SLUG: &'static str = "glr";
        const NAME: &'static str = "GLR";
        const GROUP: MethodGroup = MethodGroup::Extra;
        const NEEDS_GPS: bool = true;

        fn save(det: &Self::Detector) -> Result<Vec<StateFile>, String> {
            save_json(det)
        }

        fn load(state: &SavedState<'_>) -> Result<Self::Detector, ModelDirError> {
            load_json(state)
        }
    }
}

impl Method {
    /// Parses a [`Method::slug`] or [`Method::name`] (case-insensitive).
    ///
    /// # Errors
    /// [`UnknownMethod`].
    pub fn parse(s: &str) -> Result<Self, UnknownMethod> {
        let s = s.trim().to_ascii_lowercase();
        Method::ALL
            .iter()
            .copied()
            .find(|m| m.slug() == s || m.name().to_ascii_lowercase() == s)
            .ok_or(UnknownMethod(s))
    }

    /// The method whose table name is exactly `name`.
    ///
    /// # Errors
    /// [`UnknownMethod`].
    pub fn from_name(name: &str) -> Result<Self, UnknownMethod> {
        Method::ALL.iter().copied().find(|m| m.name() == name).ok_or_else(|| UnknownMethod(name.to_owned()))
    }

    /// Position in table order.
    #[must_use]
    pub fn rank(self) -> usize {
        Method::ALL.iter().position(|m| *m == self).unwrap_or(Method::ALL.len())
    }

    /// Window length of a windowed method with configurations `cfgs`, `None` for the others.
    #[must_use]
    pub fn window_len(self, cfgs: &MethodConfigs) -> Option<usize> {
        struct Op;
        impl Visit for Op {
            type Output = Option<usize>;
            fn visit<S: MethodSpec>(self, cfg: &S) -> Option<usize> {
                cfg.window_len()
            }
        }
        self.visit(cfgs, Op)
    }

    /// Canonical JSON of this method's configuration (hashed into the run cache key).
    #[must_use]
    pub fn config_json(self, cfgs: &MethodConfigs) -> String {
        struct Op;
        impl Visit for Op {
            type Output = String;
            fn visit<S: MethodSpec>(self, cfg: &S) -> String {
                serde_json::to_string(cfg).unwrap_or_default()
            }
        }
        self.visit(cfgs, Op)
    }

    /// Checks this method's configuration against its budgets.
    ///
    /// # Errors
    /// The first bad field, as text.
    pub fn check(self, cfgs: &MethodConfigs) -> Result<(), String> {
        struct Op;
        impl Visit for Op {
            type Output = Result<(), String>;
            fn visit<S: MethodSpec>(self, cfg: &S) -> Result<(), String> {
                cfg.check()
            }
        }
        self.visit(cfgs, Op)
    }

    /// Fits this method with `cfgs` on `train`, choosing its thresholds on `valid`.
    ///
    /// # Errors
    /// The method's own error, as text.
    pub fn fit(
        self,
        cfgs: &MethodConfigs,
        train: &LabelledResidues,
        valid: &LabelledResidues,
    ) -> Result<Box<dyn Detector>, String> {
        struct Op<'a>(&'a LabelledResidues, &'a LabelledResidues);
        impl Visit for Op<'_> {
            type Output = Result<Box<dyn Detector>, String>;
            fn visit<S: MethodSpec>(self, cfg: &S) -> Self::Output {
                cfg.fit(self.0, self.1).map(|d| Box::new(d) as Box<dyn Detector>).map_err(|e| e.to_string())
            }
        }
        self.visit(cfgs, Op(train, valid))
    }
}

impl Method {
    /// Fits this method as [`Method::fit`] does and encodes the fitted state
    /// ([`MethodSpec::save`]).
    ///
    /// # Errors
    /// The method's fit or save error, as text.
    pub fn fit_and_save(
        self,
        cfgs: &MethodConfigs,
        train: &LabelledResidues,
        valid: &LabelledResidues,
    ) -> Result<(Box<dyn Detector>, Vec<StateFile>), String> {
        struct Op<'a>(&'a LabelledResidues, &'a LabelledResidues);
        impl Visit for Op<'_> {
            type Output = Result<(Box<dyn Detector>, Vec<StateFile>), String>;
            fn visit<S: MethodSpec>(self, cfg: &S) -> Self::Output {
                let det = cfg.fit(self.0, self.1).map_err(|e| e.to_string())?;
                let files = S::save(&det).map_err(|e| format!("saving the fitted state: {e}"))?;
                Ok((Box::new(det), files))
            }
        }
        self.visit(cfgs, Op(train, valid))
    }

    /// Loads this method's fitted state saved by [`Method::fit_and_save`] (never fits).
    ///
    /// # Errors
    /// [`ModelDirError`] naming the file.
    pub fn load(self, state: &SavedState<'_>) -> Result<Box<dyn Detector>, ModelDirError> {
        struct Op<'a, 's>(&'a SavedState<'s>);
        impl Visit for Op<'_, '_> {
            type Output = Result<Box<dyn Detector>, ModelDirError>;
            fn visit<S: MethodSpec>(self, _cfg: &S) -> Self::Output {
                Ok(Box::new(S::load(self.0)?))
            }
        }
        self.visit(&MethodConfigs::default(), Op(state))
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = UnknownMethod;

    fn from_str(s: &str) -> Result<Self, UnknownMethod> {
        Self::parse(s)
    }
}

/// A method is stored by its slug (`model.json`, `--method`).
impl Serialize for Method {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.slug())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Method::ALL.iter().copied().find(|m| m.slug() == s).ok_or_else(|| serde::de::Error::custom(UnknownMethod(s)))
    }
}

/// Serde of a [`Method`] by its table name (the `method` column of `results.csv`).
pub mod by_name {
    use serde::{Deserialize, Deserializer, Serializer};

    use super::Method;

    /// Writes the table name.
    ///
    /// # Errors
    /// The serialiser's.
    pub fn serialize<S: Serializer>(m: &Method, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(m.name())
    }

    /// Reads a table name.
    ///
    /// # Errors
    /// An unknown name.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Method, D::Error> {
        let s = String::deserialize(d)?;
        Method::from_name(&s).map_err(serde::de::Error::custom)
    }
}

impl MethodConfigs {
    /// The configuration of the full run: every method's defaults, with per-epoch progress bars
    /// off (the runner shows its own). The defaults train every learning method on every
    /// window of its training data in every epoch until validation stops improving
    /// (docs/decisions/004-training-budget.md).
    #[must_use]
    pub fn full() -> Self {
        struct Quiet;
        impl VisitMut for Quiet {
            fn visit<S: MethodSpec>(&mut self, cfg: &mut S) {
                cfg.quiet();
            }
        }
        let mut c = Self::default();
        c.visit_all_mut(&mut Quiet);
        c
    }

    /// The configuration of `--quick`: small networks and few epochs, so the whole pipeline runs
    /// in about a minute. Its numbers are a smoke test, not results.
    #[must_use]
    pub fn quick() -> Self {
        struct Quick;
        impl VisitMut for Quick {
            fn visit<S: MethodSpec>(&mut self, cfg: &mut S) {
                cfg.quick();
            }
        }
        let mut c = Self::full();
        c.visit_all_mut(&mut Quick);
        c
    }

    /// A copy whose random parts (weights, shuffling, subsampling) are seeded by `seed`.
    #[must_use]
    pub fn seeded(&self, seed: u64) -> Self {
        struct Seed(u64);
        impl VisitMut for Seed {
            fn visit<S: MethodSpec>(&mut self, cfg: &mut S) {
                cfg.seed(self.0);
            }
        }
        let mut c = self.clone();
        c.visit_all_mut(&mut Seed(seed));
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_unique() {
        for (i, m) in Method::ALL.iter().enumerate() {
            assert_eq!(Method::parse(m.slug()).unwrap(), *m);
            assert_eq!(Method::parse(m.name()).unwrap(), *m);
            assert_eq!(Method::from_name(m.name()).unwrap(), *m);
            assert_eq!(m.rank(), i);
            assert!(Method::ALL[..i].iter().all(|o| o.slug() != m.slug() && o.name() != m.name()));
            let json = serde_json::to_string(m).unwrap();
            assert_eq!(serde_json::from_str::<Method>(&json).unwrap(), *m);
        }
        assert!(Method::parse("nope").unwrap_err().to_string().contains("px4-gate"));
    }

    #[test]
    fn groups_are_contiguous_in_table_order() {
        let groups: Vec<MethodGroup> = Method::ALL.iter().map(|m| m.group()).collect();
        assert!(groups.windows(2).all(|w| w[0] <= w[1]), "{groups:?}");
    }

    #[test]
    fn quick_networks_share_one_window() {
        let c = MethodConfigs::quick();
        assert_eq!(c.cnn.0.window, c.quadformer.window);
        assert_eq!(c.lstm.0.window, c.quadformer.window);
        let s = c.seeded(7);
        assert_eq!((s.cnn.0.seed, s.lstm.0.train.seed, s.svm.seed, s.quadformer.train.seed), (7, 7, 7, 7));
    }
}
