//! Command-line interface: raw arguments are parsed here and turned into a validated
//! [`Config`](crate::Config) once; `main` only maps results to exit codes.

use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use std::str::FromStr;

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

/// The configuration options every command that reads `config/default.toml` takes.
#[derive(Debug, Args, Clone)]
pub struct ConfigOpts {
    /// Configuration file (TOML) overlaid on config/default.toml.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override one setting, e.g. --set tiling.tile_size_m=25 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// Options shared by the processing commands.
#[derive(Debug, Args, Clone)]
pub struct RunOpts {
    /// Configuration file and `--set` overrides.
    #[command(flatten)]
    pub cfg: ConfigOpts,
    /// Memory budget in MiB (pipeline.memory_budget_mb).
    #[arg(long)]
    pub memory_budget: Option<u64>,
    /// Worker threads (pipeline.threads; 0 = all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Replace an earlier run's outputs in the output directory (output.overwrite): exactly
    /// the files that run recorded are removed first; other files are never touched.
    #[arg(long)]
    pub overwrite: bool,
    /// Start over instead of resuming the interrupted run in the output directory
    /// (output.restart): that run's files are removed first, as with --overwrite.
    #[arg(long)]
    pub restart: bool,
    /// Skip unreadable inputs and failed tiles, list them in summary.json and finish the
    /// rest; exit code 3 when anything was skipped (pipeline.keep_going).
    #[arg(long)]
    pub keep_going: bool,
}

impl RunOpts {
    /// All overrides, the dedicated flags last so they win.
    pub fn overrides(&self) -> Vec<String> {
        let mut v = self.cfg.set.clone();
        if let Some(m) = self.memory_budget {
            v.push(format!("pipeline.memory_budget_mb={m}"));
        }
        if let Some(t) = self.threads {
            v.push(format!("pipeline.threads={t}"));
        }
        if self.overwrite {
            v.push("output.overwrite=true".into());
        }
        if self.restart {
            v.push("output.restart=true".into());
        }
        if self.keep_going {
            v.push("pipeline.keep_going=true".into());
        }
        v
    }
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Process LAS/LAZ files and MCAP drives (or directories of them) into labelled tiles.
    ///
    /// With `--plan DIR`: runs one task of a region plan (`tessera plan`) into
    /// DIR/tasks/, with the plan's inputs and configuration; `tessera stitch DIR` joins the
    /// tasks. The task index comes from `--task`, else from `SLURM_ARRAY_TASK_ID`,
    /// `JOB_COMPLETION_INDEX` or `AWS_BATCH_JOB_ARRAY_INDEX`.
    Run {
        /// Input files or directories.
        #[arg(required_unless_present = "plan", conflicts_with = "plan")]
        inputs: Vec<PathBuf>,
        /// Output directory.
        #[arg(long, required_unless_present = "plan", conflicts_with = "plan")]
        out: Option<PathBuf>,
        /// A region plan directory: run one of its tasks.
        #[arg(long)]
        plan: Option<PathBuf>,
        /// The task to run (0-based).
        #[arg(long, requires = "plan")]
        task: Option<usize>,
        /// Shared options.
        #[command(flatten)]
        opts: RunOpts,
    },
    /// Join the finished tasks of a region plan into the region's tiles: segments stitched
    /// across task borders, global segment ids, one summary — the output of one `tessera run`
    /// of the region.
    Stitch {
        /// The plan directory.
        dir: PathBuf,
        /// Replace the outputs of an earlier stitch (e.g. one that was interrupted).
        #[arg(long)]
        overwrite: bool,
    },
    /// Rebuild `report.html` in the output directory of a finished run (or stitch) from its
    /// summary.json and tiles: top views by class, segment and height with the tile grid,
    /// errors and a confusion matrix when the tiles carry a gt_class attribute, stage costs.
    Report {
        /// The output directory.
        dir: PathBuf,
    },
    /// Write Slurm batch scripts for a region plan: a job array of its tasks and a stitch job
    /// that runs after all of them succeeded (DIR/slurm/).
    Slurm {
        /// The plan directory.
        dir: PathBuf,
        /// Number of tasks (must match the plan; default: the plan's).
        #[arg(long)]
        tasks: Option<usize>,
        /// Slurm partition.
        #[arg(long)]
        partition: Option<String>,
        /// Time limit per task (Slurm format, e.g. 02:00:00).
        #[arg(long)]
        time: Option<String>,
        /// Tasks running at once (the array's `%` throttle).
        #[arg(long)]
        parallel: Option<usize>,
        /// Submit with sbatch instead of only writing the scripts.
        #[arg(long)]
        submit: bool,
    },
    /// Plan a region for a cluster: from the LAS/LAZ headers only, the grid tiles with their
    /// estimated points, cut into tasks of spatially compact blocks balanced by points
    /// (writes DIR/plan.json, DIR/tiles.tsv and DIR/config.toml, the settings every task
    /// runs with).
    Plan {
        /// Input files or directories (LAS/LAZ).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Directory the plan is written into.
        #[arg(long)]
        out: PathBuf,
        /// Number of tasks.
        #[arg(long, default_value_t = 1)]
        tasks: usize,
        /// Configuration (the grid: `tiling.*`).
        #[command(flatten)]
        cfg: ConfigOpts,
    },
    /// Generate a deterministic synthetic street scene with ground truth.
    Synth(SynthArgs),
    /// Density reduction by minimum point spacing (Sapkota §5.3), streaming: a point is kept
    /// unless a kept point lies within the spacing.
    Thin {
        /// Minimum distance between kept points, metres.
        #[arg(long)]
        spacing: f64,
        /// Input LAS/LAZ file.
        input: PathBuf,
        /// Output LAS/LAZ file (LAZ if the name ends in .laz).
        output: PathBuf,
    },
    /// Summarise training samples for the labelling stage (mean and σ of L*, a*, b* per sample)
    /// into a JSON file for `label.samples`.
    Samples(SamplesArgs),
    /// Train the labelling classifier (`label.model`) on classified LAS/LAZ files: the
    /// pipeline runs on them as configured, and the descriptors of every point whose
    /// reference class the class map names become training samples of a random forest.
    Train(TrainArgs),
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
    /// Print facts about a LAS/LAZ file (header) or an MCAP recording (topics, message
    /// counts, time span, point counts).
    Info {
        /// The file.
        file: PathBuf,
    },
}

/// Arguments of `tessera synth`.
#[derive(Debug, Args, Clone)]
pub struct SynthArgs {
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Length of the drive, metres.
    #[arg(long, default_value_t = 200.0)]
    pub length_m: f64,
    /// Point density at 5 m from the drive line, points per m².
    #[arg(long)]
    pub points_per_m2: Option<f64>,
    /// Length of the drive written to each output file, metres.
    #[arg(long, default_value_t = 50.0)]
    pub file_length_m: f64,
    /// Which scene: a street drive, or a row of coloured houses (segmentation gate).
    #[arg(long, value_enum, default_value_t = SceneKind::Street)]
    pub scene: SceneKind,
    /// Number of houses (buildings scene).
    #[arg(long, default_value_t = 4)]
    pub houses: usize,
    /// Write the street as a drive recording instead: a simulated spinning LiDAR, as ROS 2
    /// MCAP (PointCloud2 + /tf), with truth fields per point (`drive.mcap`).
    #[arg(long)]
    pub mcap: bool,
    /// Beams of the simulated LiDAR (--mcap).
    #[arg(long, default_value_t = 32)]
    pub rings: u32,
    /// Firings per revolution of the simulated LiDAR (--mcap).
    #[arg(long, default_value_t = 1024)]
    pub columns: u32,
    /// With --mcap: instead of the recording, write every K-th revolution as its own LAS file
    /// (`scan_NNNNN.laz`: one scan in the world frame, truth attributes, no colour, as a bare
    /// spinning LiDAR gives it), e.g. training data for `tessera train`.
    #[arg(long, value_name = "K")]
    pub scans_every: Option<u64>,
}

/// Arguments of `tessera samples`.
#[derive(Debug, Args, Clone)]
pub struct SamplesArgs {
    /// A LAS/LAZ of classified points (one sample per class and block), or a GeoJSON of
    /// polygons with a `class` property selecting points of `--input` (one per polygon).
    #[arg(long)]
    pub from: PathBuf,
    /// Point files the polygons select from (GeoJSON only).
    #[arg(long)]
    pub input: Vec<PathBuf>,
    /// Attribute holding the class codes of a LAS/LAZ source.
    #[arg(long, default_value = "classification")]
    pub field: String,
    /// Only points of these classes enter polygon samples (default: ground, 2).
    #[arg(long, value_delimiter = ',', default_value = "2")]
    pub point_classes: Vec<u8>,
    /// Sample classes kept from a LAS/LAZ source (default: every class but 0, 1, 2, 7, 18).
    #[arg(long, value_delimiter = ',')]
    pub classes: Vec<u8>,
    /// Block size splitting a LAS/LAZ source into samples, metres.
    #[arg(long, default_value_t = 5.0)]
    pub block_m: f64,
    /// Fewer coloured points than this: not a sample.
    #[arg(long, default_value_t = 30)]
    pub min_points: u64,
    /// Output JSON.
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `tessera train`.
#[derive(Debug, Args, Clone)]
pub struct TrainArgs {
    /// Classified LAS/LAZ files or directories (the reference classes in `--ref-field`).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Class map (TOML, `field = …` and `[[class]] code = …, reference = […]`): reference
    /// codes → tessera codes, e.g. config/semantickitti.toml. Repeatable: each file uses the
    /// first map whose `field` it has (so a map of a truth attribute such as `gt_class`
    /// goes before one of `classification`). Points of unmapped codes are not trained on.
    #[arg(long, required = true)]
    pub class_map: Vec<PathBuf>,
    /// The model file to write (JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Configuration (the pipeline the model will run in; `label.train.*` for the forest).
    #[command(flatten)]
    pub cfg: ConfigOpts,
}

/// Synthetic scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SceneKind {
    /// Street drive with road, kerbs, facades, trees, poles and cars.
    Street,
    /// Row of gabled houses with dormers, framed windows, doors and a shadow.
    Buildings,
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
    /// Labels: confusion matrix, omission and commission errors, mapping accuracy, F1
    /// (street-level document Tables 13–16).
    Labels {
        /// Reference LAS/LAZ file or directory.
        #[arg(long)]
        reference: PathBuf,
        /// Result LAS/LAZ file or directory of tiles.
        #[arg(long)]
        result: PathBuf,
        /// Reference attribute with class codes (classification or an extra-bytes name).
        #[arg(long, default_value = "classification")]
        ref_field: String,
        /// Result attribute with class codes.
        #[arg(long, default_value = "classification")]
        res_field: String,
        /// Scored reference classes (comma-separated; default: all present).
        #[arg(long, value_delimiter = ',')]
        classes: Vec<u8>,
        /// Map result codes onto one code before scoring, e.g. 2=11,64,65,66,67 (repeatable).
        #[arg(long = "map", value_name = "TO=FROM,...")]
        map: Vec<ClassMap>,
        /// Score only reference points with x0 <= x < x1 (e.g. away from training samples).
        #[arg(long, value_name = "X0,X1")]
        x_range: Option<XRange>,
        /// Class map (TOML, e.g. config/semantickitti.toml): reference codes are translated to
        /// tessera codes before scoring, unmapped ones are not scored; the scored classes
        /// default to the map's.
        #[arg(long, value_name = "FILE.toml")]
        class_map: Option<PathBuf>,
        /// Leave out reference points inside the polygons of this GeoJSON file (Polygon /
        /// MultiPolygon, in the data's CRS; repeatable), e.g. a block the reference left
        /// unclassified.
        #[arg(long, value_name = "FILE.geojson")]
        exclude: Vec<PathBuf>,
        /// Coordinate precision for matching points, metres.
        #[arg(long, default_value_t = 0.001)]
        match_precision_m: f64,
        /// Score only reference points found in the result.
        #[arg(long)]
        allow_unmatched: bool,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Segmentation: Hoover / Sapkota (§5.2) correct, over-, under-segmentation, missed and
    /// noise at tolerances 0.51–0.99, and the RMSE of angles between matched planes.
    Segments {
        /// Reference LAS/LAZ file or directory.
        #[arg(long)]
        reference: PathBuf,
        /// Result LAS/LAZ file or directory of tiles.
        #[arg(long)]
        result: PathBuf,
        /// Reference attribute with segment ids (extra-bytes name or a standard field).
        #[arg(long, default_value = "gt_segment")]
        ref_field: String,
        /// Result attribute with segment ids.
        #[arg(long, default_value = "segment_id")]
        res_field: String,
        /// Score only reference points whose FIELD is one of the values, e.g. gt_class=6.
        #[arg(long, value_name = "FIELD=V1,V2")]
        restrict: Option<Restrict>,
        /// Result ids are global (stitched): do not make them unique per file.
        #[arg(long)]
        global_ids: bool,
        /// Tolerances (comma-separated, each in (0.5, 1]).
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "0.51,0.6,0.7,0.8,0.9,0.99"
        )]
        tolerance: Vec<f64>,
        /// Coordinate precision for matching points, metres.
        #[arg(long, default_value_t = 0.001)]
        match_precision_m: f64,
        /// Score only reference points found in the result.
        #[arg(long)]
        allow_unmatched: bool,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

/// A comma-separated list of values (spaces around items allowed); the error names the item.
fn parse_list<T: FromStr>(s: &str) -> Result<Vec<T>, String>
where
    T::Err: std::fmt::Display,
{
    s.split(',')
        .map(|x| x.trim().parse::<T>().map_err(|e| format!("{x}: {e}")))
        .collect()
}

/// `--map TO=FROM,...`: result codes mapped onto one code before scoring.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClassMap {
    /// The code scored.
    pub to: u8,
    /// The result codes that count as `to`.
    pub from: Vec<u8>,
}

impl FromStr for ClassMap {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (to, from) = s
            .split_once('=')
            .ok_or_else(|| "expected TO=FROM,...".to_string())?;
        let to = to.trim().parse::<u8>().map_err(|e| format!("{to}: {e}"))?;
        Ok(ClassMap {
            to,
            from: parse_list(from)?,
        })
    }
}

/// `--x-range X0,X1` with X0 < X1 (finite).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XRange(pub f64, pub f64);

impl FromStr for XRange {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match parse_list::<f64>(s)?[..] {
            [a, b] if a.is_finite() && b.is_finite() && a < b => Ok(XRange(a, b)),
            _ => Err("expected X0,X1 with X0 < X1".into()),
        }
    }
}

/// `--restrict FIELD=V1,V2,...`: score only reference points whose FIELD is one of the values.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Restrict {
    /// Attribute name.
    pub field: String,
    /// Values kept.
    pub values: Vec<u32>,
}

impl FromStr for Restrict {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (field, v) = s
            .split_once('=')
            .ok_or_else(|| "expected FIELD=V1,V2,...".to_string())?;
        if field.trim().is_empty() {
            return Err("expected FIELD=V1,V2,... (no field name)".into());
        }
        let values = parse_list(v)?;
        Ok(Restrict {
            field: field.trim().to_string(),
            values,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn argument_types_parse_and_refuse() {
        assert_eq!(
            "2=11, 64,65".parse::<ClassMap>().unwrap(),
            ClassMap {
                to: 2,
                from: vec![11, 64, 65]
            }
        );
        assert!("2:11".parse::<ClassMap>().is_err());
        assert!("2=300".parse::<ClassMap>().is_err());
        assert_eq!("1.5, 9".parse::<XRange>().unwrap(), XRange(1.5, 9.0));
        for bad in ["9,1", "1", "1,2,3", "a,b", "NaN,1", "1,inf"] {
            assert!(bad.parse::<XRange>().is_err(), "{bad}");
        }
        assert_eq!(
            "gt_class=6,2".parse::<Restrict>().unwrap(),
            Restrict {
                field: "gt_class".into(),
                values: vec![6, 2]
            }
        );
        assert!("=6".parse::<Restrict>().is_err());
        assert!("gt_class".parse::<Restrict>().is_err());
    }
}
