//! Cells of the experiment matrix (UAV model × noise shape × attack model, the columns of the
//! paper's tab:comprehensive_analysis1 and tab:comprehensive_analysis2) and their one naming
//! scheme, `m1-exponential-a2`: what `--cells` and `--cell` take, and every file name derived
//! from a cell (run caches, ROC figures, dataset cache files).

use std::fmt;

use attack_inject::AttackKind;
use ekf_residue::residues::ModelKind;
use serde::{Deserialize, Serialize};
use uav_dynamics::noise::NoiseShape;

/// The UAV model of a cell (paper eq:model1f / eq:model2f).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum UavModel {
    /// Model I: 15 states, pose measurement.
    #[serde(rename = "I")]
    I,
    /// Model II: 21 states, GPS and VO relative pose.
    #[serde(rename = "II")]
    II,
}

/// The sensor-noise shape of a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NoiseModel {
    /// Gaussian (not a column of the paper's tables; used by ablations).
    Gaussian,
    /// Centred exponential at the Gaussian's σ.
    Exponential,
    /// Laplace at the Gaussian's σ.
    Laplace,
}

/// The attack model of a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum AttackModel {
    /// Attack I: sparse FDI bursts.
    #[serde(rename = "I")]
    I,
    /// Attack II: persistent FDI (bias or slow ramp).
    #[serde(rename = "II")]
    II,
}

impl UavModel {
    /// Both models, in table order.
    pub const ALL: [Self; 2] = [Self::I, Self::II];

    /// Name part of a cell slug: `m1`, `m2`.
    #[must_use]
    pub const fn slug(self) -> &'static str {
        match self {
            Self::I => "m1",
            Self::II => "m2",
        }
    }

    /// Roman numeral, as in "Model II".
    #[must_use]
    pub const fn roman(self) -> &'static str {
        match self {
            Self::I => "I",
            Self::II => "II",
        }
    }

    /// The residue generator's model.
    #[must_use]
    pub const fn kind(self) -> ModelKind {
        match self {
            Self::I => ModelKind::ModelI,
            Self::II => ModelKind::ModelII,
        }
    }

    /// The cell model of a residue generator's model.
    #[must_use]
    pub const fn of_kind(kind: ModelKind) -> Self {
        match kind {
            ModelKind::ModelI => Self::I,
            ModelKind::ModelII => Self::II,
        }
    }
}

impl NoiseModel {
    /// Every shape, in table order.
    pub const ALL: [Self; 3] = [Self::Gaussian, Self::Exponential, Self::Laplace];

    /// Lowercase name, as in cell slugs (`exponential`).
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Gaussian => "gaussian",
            Self::Exponential => "exponential",
            Self::Laplace => "laplace",
        }
    }

    /// The simulator's noise shape.
    #[must_use]
    pub const fn shape(self) -> NoiseShape {
        match self {
            Self::Gaussian => NoiseShape::Gaussian,
            Self::Exponential => NoiseShape::Exponential,
            Self::Laplace => NoiseShape::Laplace,
        }
    }

    /// The cell noise of a simulator noise shape.
    #[must_use]
    pub const fn of_shape(shape: NoiseShape) -> Self {
        match shape {
            NoiseShape::Gaussian => Self::Gaussian,
            NoiseShape::Exponential => Self::Exponential,
            NoiseShape::Laplace => Self::Laplace,
        }
    }
}

impl AttackModel {
    /// Both attack models, in table order.
    pub const ALL: [Self; 2] = [Self::I, Self::II];

    /// Name part of a cell slug: `a1`, `a2`.
    #[must_use]
    pub const fn slug(self) -> &'static str {
        match self {
            Self::I => "a1",
            Self::II => "a2",
        }
    }

    /// Roman numeral, as in "Attack II".
    #[must_use]
    pub const fn roman(self) -> &'static str {
        match self {
            Self::I => "I",
            Self::II => "II",
        }
    }

    /// The injector's attack kind.
    #[must_use]
    pub const fn kind(self) -> AttackKind {
        match self {
            Self::I => AttackKind::Sparse,
            Self::II => AttackKind::Persistent,
        }
    }

    /// The attack model of an injector kind; `None` for kinds that are no column of the
    /// tables (replay, freeze, noise, oscillating).
    #[must_use]
    pub const fn of_kind(kind: AttackKind) -> Option<Self> {
        match kind {
            AttackKind::Sparse => Some(Self::I),
            AttackKind::Persistent => Some(Self::II),
            _ => None,
        }
    }
}

/// One cell of the experiment matrix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Cell {
    /// UAV model.
    pub model: UavModel,
    /// Noise shape.
    pub noise: NoiseModel,
    /// Attack model.
    pub attack: AttackModel,
}

/// The four columns of a table, in the paper's order.
pub const TABLE_COLUMNS: [(NoiseModel, AttackModel); 4] = [
    (NoiseModel::Exponential, AttackModel::I),
    (NoiseModel::Exponential, AttackModel::II),
    (NoiseModel::Laplace, AttackModel::I),
    (NoiseModel::Laplace, AttackModel::II),
];

/// A cell name that is not of the form [`Cell::slug`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown cell `{0}`: expected m1|m2 - gaussian|exponential|laplace - a1|a2, e.g. m1-exponential-a2")]
pub struct UnknownCell(pub String);

impl Cell {
    /// The eight cells of Tables I and II, in table order.
    #[must_use]
    pub fn table_cells() -> Vec<Cell> {
        UavModel::ALL
            .into_iter()
            .flat_map(|model| TABLE_COLUMNS.map(|(noise, attack)| Cell { model, noise, attack }))
            .collect()
    }

    /// Every cell, Gaussian noise included.
    pub fn all() -> impl Iterator<Item = Cell> {
        UavModel::ALL.into_iter().flat_map(|model| {
            NoiseModel::ALL
                .into_iter()
                .flat_map(move |noise| AttackModel::ALL.into_iter().map(move |attack| Cell { model, noise, attack }))
        })
    }

    /// The file-name-safe name, e.g. `m1-exponential-a2`.
    #[must_use]
    pub fn slug(&self) -> String {
        format!("{}-{}-{}", self.model.slug(), self.noise.name(), self.attack.slug())
    }

    /// Parses a [`Cell::slug`].
    ///
    /// # Errors
    /// [`UnknownCell`] naming the valid form.
    pub fn parse(s: &str) -> Result<Cell, UnknownCell> {
        let s = s.trim();
        Cell::all().find(|c| c.slug() == s).ok_or_else(|| UnknownCell(s.to_owned()))
    }

    /// The cell of a dataset's generator parts, `None` when the attack kind is no column of the
    /// tables.
    #[must_use]
    pub fn of_parts(model: ModelKind, noise: NoiseShape, attack: AttackKind) -> Option<Cell> {
        Some(Cell {
            model: UavModel::of_kind(model),
            noise: NoiseModel::of_shape(noise),
            attack: AttackModel::of_kind(attack)?,
        })
    }

    /// The name of a dataset's generator parts: the cell slug, or for an attack kind outside the
    /// tables the slug with the kind's name in place of `a1`/`a2` (e.g. `m2-gaussian-replay`).
    #[must_use]
    pub fn name_of_parts(model: ModelKind, noise: NoiseShape, attack: AttackKind) -> String {
        match Cell::of_parts(model, noise, attack) {
            Some(c) => c.slug(),
            None => {
                format!("{}-{}-{}", UavModel::of_kind(model).slug(), NoiseModel::of_shape(noise).name(), attack.name())
            }
        }
    }
}

impl std::str::FromStr for Cell {
    type Err = UnknownCell;

    fn from_str(s: &str) -> Result<Self, UnknownCell> {
        Cell::parse(s)
    }
}

impl fmt::Display for Cell {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Model {}, {} noise, Attack {}", self.model.roman(), self.noise.name(), self.attack.roman())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_parse_from_their_slugs() {
        assert_eq!(Cell::all().count(), 12);
        for c in Cell::all() {
            assert_eq!(Cell::parse(&c.slug()).unwrap(), c);
            assert_eq!(Cell::name_of_parts(c.model.kind(), c.noise.shape(), c.attack.kind()), c.slug());
        }
        assert_eq!(Cell::table_cells().len(), 8);
        assert!(Cell::parse("m3-laplace-a1").is_err());
        assert_eq!(
            Cell::name_of_parts(ModelKind::ModelII, NoiseShape::Gaussian, AttackKind::Replay),
            "m2-gaussian-replay"
        );
    }
}
