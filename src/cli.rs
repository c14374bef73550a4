//! Command-line interface: raw arguments are parsed here and turned into a validated
//! [`Config`](crate::Config) once; `main` only maps results to exit codes.

use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;

/// tessera — streaming out-of-core tile processor for mobile-mapping point clouds.
#[derive(Debug, Parser)]
#[command(name = "tessera", version, about)]
pub struct Cli {
    /// Less output (errors only).
    #[arg(short, long, global = true)]
    pub quiet: bool,
    /// More output (repeat for debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    /// The command.
    #[command(subcommand)]
    pub command: Command,
}

/// Options shared by the processing commands.
#[derive(Debug, Args, Clone)]
pub struct RunOpts {
    /// Configuration file (TOML) overlaid on config/default.toml.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override one setting, e.g. --set tiling.tile_size_m=25 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Memory budget in MiB (pipeline.memory_budget_mb).
    #[arg(long)]
    pub memory_budget: Option<u64>,
    /// Worker threads (pipeline.threads; 0 = all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

impl RunOpts {
    /// All overrides, the dedicated flags last so they win.
    pub fn overrides(&self) -> Vec<String> {
        let mut v = self.set.clone();
        if let Some(m) = self.memory_budget {
            v.push(format!("pipeline.memory_budget_mb={m}"));
        }
        if let Some(t) = self.threads {
            v.push(format!("pipeline.threads={t}"));
        }
        v
    }
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Process LAS/LAZ files (or directories of them) into labelled tiles.
    Run {
        /// Input files or directories.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Shared options.
        #[command(flatten)]
        opts: RunOpts,
    },
    /// Generate a deterministic synthetic street scene with ground truth.
    Synth {
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Length of the drive, metres.
        #[arg(long, default_value_t = 200.0)]
        length_m: f64,
        /// Point density at 5 m from the drive line, points per m².
        #[arg(long)]
        points_per_m2: Option<f64>,
        /// Length of the drive written to each output file, metres.
        #[arg(long, default_value_t = 50.0)]
        file_length_m: f64,
    },
    /// Synthesise a small street scene and run the pipeline on it.
    Demo {
        /// Output directory (default: ./tessera-demo).
        #[arg(long, default_value = "tessera-demo")]
        out: PathBuf,
        /// Length of the synthetic drive, metres.
        #[arg(long, default_value_t = 150.0)]
        length_m: f64,
        /// Shared options.
        #[command(flatten)]
        opts: RunOpts,
    },
    /// Evaluate results against reference labels.
    Eval {
        /// What to evaluate.
        #[command(subcommand)]
        what: EvalCommand,
    },
    /// Print facts about a LAS/LAZ file.
    Info {
        /// The file.
        file: PathBuf,
    },
}

/// Evaluations.
#[derive(Debug, Subcommand)]
pub enum EvalCommand {
    /// Ground filtering: Type I, Type II, total error, Cohen's kappa (ISPRS WG III/3).
    Ground {
        /// Reference LAS/LAZ file or directory.
        #[arg(long)]
        reference: PathBuf,
        /// Result LAS/LAZ file or directory of tiles.
        #[arg(long)]
        result: PathBuf,
        /// Reference classes that mean ground (comma-separated; ISPRS uses 2).
        #[arg(long, value_delimiter = ',', default_value = "2")]
        ref_ground_class: Vec<u8>,
        /// Result classes that mean ground.
        #[arg(long, value_delimiter = ',', default_value = "2")]
        result_ground_class: Vec<u8>,
        /// Coordinate precision for matching points, metres.
        #[arg(long, default_value_t = 0.001)]
        match_precision_m: f64,
        /// Score only reference points found in the result (e.g. ISPRS samples inside a
        /// filtered site file); otherwise a missing point is an error.
        #[arg(long)]
        allow_unmatched: bool,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}
