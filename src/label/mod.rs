//! Labelling (street-level document `003`, chapter 5 §7–9): ground subclasses from colour
//! regions and training samples ([`ground`], [`samples`]), non-ground classes from segment and
//! object geometry ([`objects`]); optionally a trained classifier over multi-scale point
//! descriptors ([`descriptors`], [`forest`], [`model`]; `tessera train`) that refines them.

pub mod descriptors;
pub mod forest;
pub mod ground;
pub mod kerbs;
pub mod model;
pub mod objects;
pub mod samples;

pub use ground::{label_ground, GroundLabelParams, GroundLabels};
pub use objects::{classify_objects, ObjectClass, ObjectInput, ObjectParams};
pub use samples::{Sample, SampleSet};

use serde::{Deserialize, Serialize};

/// Class codes written for the non-ground classes and for ground points no sample matched.
/// Ground subclass codes come from the training samples themselves. ASPRS LAS 1.4 codes where
/// they exist; user codes ≥ 64 otherwise (see `config/default.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelCodes {
    /// Ground points whose region matched no sample (or unsupervised runs).
    pub unknown_ground: u8,
    /// Buildings and facades (ASPRS 6).
    pub building: u8,
    /// Trees (ASPRS 5).
    pub high_vegetation: u8,
    /// Pole-like objects (user code).
    pub pole: u8,
    /// Vehicles (user code).
    pub vehicle: u8,
    /// Other non-ground (ASPRS 1, unclassified).
    pub other: u8,
}

impl Default for LabelCodes {
    fn default() -> Self {
        LabelCodes {
            unknown_ground: 2,
            building: 6,
            high_vegetation: 5,
            pole: 69,
            vehicle: 70,
            other: 1,
        }
    }
}

impl LabelCodes {
    /// The code of a non-ground class.
    pub fn of(&self, c: ObjectClass) -> u8 {
        match c {
            ObjectClass::Building => self.building,
            ObjectClass::HighVegetation => self.high_vegetation,
            ObjectClass::Pole => self.pole,
            ObjectClass::Vehicle => self.vehicle,
            ObjectClass::Other => self.other,
        }
    }

    /// Largest code in use.
    pub fn max(&self) -> u8 {
        [
            self.unknown_ground,
            self.building,
            self.high_vegetation,
            self.pole,
            self.vehicle,
            self.other,
        ]
        .into_iter()
        .max()
        .unwrap_or(0)
    }
}
