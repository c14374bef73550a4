//! The stages run by the workers on every tile, each in its own module that owns everything
//! about it: its configuration section (parsed and checked by the stage), its memory model
//! (what the budget plan charges per point, its context width), what it writes, and its
//! adapter to the pipeline ([`Stage`]). [`REGISTRY`] is the only list of stages.
//!
//! | module | stage | writes |
//! |---|---|---|
//! | [`stats`] | `stats` | nothing (per-tile statistics) |
//! | [`ground`] | `ground` | ASPRS classes 2 / 7 / non-ground |
//! | [`segment`] | `segment` | `segment_id`, the segment table |
//! | [`label`] | `label` | ground subclasses and object classes |

pub mod ground;
pub mod label;
pub mod registry;
pub mod segment;
pub mod stage;
pub mod stats;

pub use registry::{build_stages, validate_stages, REGISTRY};
pub use stage::{parse_section, Attribute, Stage, StageSpec, StageWork, TileReport};
