//! tessera — a streaming, out-of-core tile processor for country-scale mobile-mapping point
//! clouds: LAS/LAZ in, overlap-buffered tiles through bounded channels, labelled LAZ out, with
//! memory bounded by one budget whatever the input size.
#![deny(missing_docs)]
#![deny(unsafe_code)]

pub mod budget;
pub mod cli;
pub mod config;
pub mod error;
pub mod eval;
pub mod geom;
pub mod ground;
pub mod io;
pub mod label;
pub mod model;
pub mod pipeline;
pub mod region;
pub mod report;
pub mod rng;
pub mod segment;
pub mod stages;
pub mod stitch;
pub mod synth;
pub mod sys;
pub mod thin;
pub mod tiling;

pub use config::Config;
pub use error::{Error, Result};
