//! Configuration: `config/default.toml` (compiled in, the single source of defaults), overlaid
//! by an optional user file, overlaid by `--set section.key=value` pairs, then validated once.
//!
//! This module only composes sections: the run's own (`[tiling]`, `[pipeline]`, `[output]`,
//! `[stages]`), those of I/O and stitching, and the stage sections (`[ground]`, `[segment]`,
//! `[label]`, …), which it keeps as written and hands to the stage of that name: each stage
//! parses and checks its own (see [`crate::stages`]). All of them are checked here, at load,
//! whether or not the stage runs.

use crate::error::{Error, Result};
use serde::Deserialize;
use std::path::Path;

/// Largest configuration file read (the defaults are ~10 KB).
const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// Keys renamed since earlier versions, `(old, new)`: configuration files and `--set` may
/// still use the old name (a warning says so); both in one file is an error.
const RENAMED: &[(&str, &str)] = &[
    ("segment.buffer_m", "segment.context_m"),
    ("label.buffer_m", "label.context_m"),
    ("tiling.thin_split_buffers", "tiling.thin_far_buffers"),
    ("tiling.split_dense_buffer_m", "tiling.dense_buffer_m"),
];

/// The compiled-in default configuration.
pub const DEFAULT_TOML: &str = include_str!("../config/default.toml");

/// Tiling parameters.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TilingParams {
    /// Core tile edge, metres.
    pub tile_size_m: f64,
    /// Overlap buffer width, metres.
    pub buffer_m: f64,
    /// Smallest core edge quadtree splitting may produce, metres.
    pub min_tile_size_m: f64,
    /// Tiles of sparse inputs grow until they are expected to hold this many points
    /// ([`crate::tiling::grid::sparse_tile_size`]); 0 keeps `tile_size_m`.
    #[serde(default)]
    pub sparse_tile_points: u64,
    /// Thin the far part of tiles' buffers (see `tiling::FarThin`).
    pub thin_far_buffers: bool,
    /// Tiles keep every buffer point within this distance of their core, metres (beyond the
    /// stages' contexts, which are always kept whole).
    pub dense_buffer_m: f64,
}

/// Pipeline resource parameters.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineParams {
    /// Memory budget, MiB.
    pub memory_budget_mb: u64,
    /// Worker threads (0 = cores).
    pub threads: usize,
    /// Spill directory ("" = inside the output directory).
    pub spill_dir: String,
    /// Skip inputs that cannot be read and tiles whose processing fails, list them in the
    /// summary and finish the rest (exit code 3) instead of stopping the run.
    #[serde(default)]
    pub keep_going: bool,
}

/// Output parameters.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputParams {
    /// "laz", "las" or "copc".
    pub format: String,
    /// "auto" or a point format number as a string or integer.
    pub point_format: toml::Value,
    /// Replace an earlier run's outputs in the output directory (only the files its journal
    /// lists); without it such a directory is refused.
    pub overwrite: bool,
    /// Start over instead of resuming an interrupted run in the output directory.
    pub restart: bool,
    /// Write `report.html` (overview rasters, tile grid, stage costs) when the run finishes.
    pub report: bool,
    /// Also write one LAS/LAZ per class code across all tiles.
    pub per_class: bool,
}

/// Stage selection.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StagesParams {
    /// Stage names in order.
    pub run: Vec<String>,
}

/// `[crs]`: the inputs' linear unit.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrsParams {
    /// "auto" (read from the inputs' CRS), "metre", "foot" or "us_survey_foot".
    pub units: String,
}

impl CrsParams {
    /// The stated unit, `None` for "auto".
    pub fn stated_unit(&self) -> Result<Option<crate::io::crs::LinearUnit>> {
        use crate::io::crs::LinearUnit;
        match self.units.as_str() {
            "auto" => Ok(None),
            "metre" | "meter" | "m" => Ok(Some(LinearUnit::metre())),
            "foot" | "ft" => Ok(Some(LinearUnit::foot())),
            "us_survey_foot" | "us_ft" => Ok(Some(LinearUnit::us_survey_foot())),
            other => Err(Error::Config(format!(
                "crs.units must be \"auto\", \"metre\", \"foot\" or \"us_survey_foot\", got \"{other}\""
            ))),
        }
    }
}

/// The whole validated configuration: only [`Config::load`] makes one (it parses the run's
/// own sections and hands the stage sections to their stages).
#[derive(Debug, Clone)]
pub struct Config {
    /// `[tiling]`
    pub tiling: TilingParams,
    /// `[pipeline]`
    pub pipeline: PipelineParams,
    /// `[output]`
    pub output: OutputParams,
    /// `[stages]`
    pub stages: StagesParams,
    /// `[mcap]`
    pub mcap: crate::io::mcap::McapParams,
    /// `[stitch]`
    pub stitch: crate::stitch::StitchParams,
    /// `[crs]`
    pub crs: CrsParams,
    /// The registered stages' sections as written (`[ground]`, `[segment]`, …), keyed by
    /// stage name; each is parsed and checked by its stage.
    pub sections: toml::Table,
    /// Every setting as `section.key = value` (defaults, file and `--set` merged), in key
    /// order: what a resumed run compares with the run it continues.
    pub effective: std::collections::BTreeMap<String, String>,
    /// The merged document all of the above were parsed from (for [`Config::in_length_unit`]).
    document: toml::Value,
}

/// Flattens a TOML document into `a.b.c = value` pairs (arrays and scalars as TOML text).
fn flatten(prefix: &str, v: &toml::Value, out: &mut std::collections::BTreeMap<String, String>) {
    match v {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        other => {
            out.insert(prefix.to_string(), other.to_string());
        }
    }
}

/// The sections that are not a stage's: what remains of the configuration once the stage
/// sections are taken out (any other key is unknown).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RunSections {
    tiling: TilingParams,
    pipeline: PipelineParams,
    output: OutputParams,
    stages: StagesParams,
    mcap: crate::io::mcap::McapParams,
    stitch: crate::stitch::StitchParams,
    crs: CrsParams,
}

impl Config {
    /// Loads defaults, then `user_file` (if any), then `overrides` (`section.key=value`).
    pub fn load(user_file: Option<&Path>, overrides: &[String]) -> Result<Config> {
        let mut root: toml::Value = toml::from_str(DEFAULT_TOML)
            .map_err(|e| Error::Config(format!("built-in defaults: {e}")))?;
        if let Some(path) = user_file {
            // Bounded and regular files only: `--config /dev/zero` or a FIFO must fail, not hang.
            let text = crate::io::files::read_text_bounded(path, MAX_CONFIG_BYTES)?;
            let mut user: toml::Value = toml::from_str(&text)
                .map_err(|e| Error::Config(format!("{}: {e}", path.display())))?;
            rename_keys(&mut user, &path.display().to_string())?;
            merge(&mut root, user);
        }
        for item in overrides {
            apply_override(&mut root, &renamed_override(item))?;
        }
        Config::from_document(root)
    }

    /// Parses and validates a merged document.
    fn from_document(mut root: toml::Value) -> Result<Config> {
        let document = root.clone();
        let mut effective = std::collections::BTreeMap::new();
        flatten("", &root, &mut effective);
        // Stage sections go to their stages; the rest must be the run's own sections.
        let mut sections = toml::Table::new();
        if let toml::Value::Table(t) = &mut root {
            let names: Vec<String> = t
                .keys()
                .filter(|k| crate::stages::registry::is_stage_section(k))
                .cloned()
                .collect();
            for k in names {
                if let Some(v) = t.remove(&k) {
                    sections.insert(k, v);
                }
            }
        }
        let run: RunSections = root
            .try_into()
            .map_err(|e: toml::de::Error| Error::Config(e.to_string()))?;
        let cfg = Config {
            tiling: run.tiling,
            pipeline: run.pipeline,
            output: run.output,
            stages: run.stages,
            mcap: run.mcap,
            stitch: run.stitch,
            crs: run.crs,
            sections,
            effective,
            document,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// The defaults alone.
    pub fn defaults() -> Result<Config> {
        Config::load(None, &[])
    }

    /// The same configuration for inputs whose coordinates are in a unit of `metres_per_unit`
    /// metres: every distance (a key ending in `_m`, each element of an array of them) is
    /// divided by it, every area (`_m2`) by its square. `[mcap]` is left alone: drives are
    /// decoded in metres whatever their output CRS. The keys converted are returned.
    ///
    /// One naming rule instead of a list of keys: a new distance parameter is converted as
    /// soon as it is named like the others (a test checks the defaults follow the rule).
    /// The tile size too is converted exactly (not rounded to whole units): tile borders
    /// change results near them, and rounding 100 m to 328 ft doubled the differences from
    /// the metre run on ISPRS samp11 (0.36 % → 0.73 %). Tile names then carry decimals.
    pub fn in_length_unit(&self, metres_per_unit: f64) -> Result<(Config, Vec<String>)> {
        fn scale(v: &mut toml::Value, f: f64) -> bool {
            match v {
                toml::Value::Float(x) => {
                    *x /= f;
                    true
                }
                toml::Value::Integer(n) => {
                    *v = toml::Value::Float(*n as f64 / f);
                    true
                }
                toml::Value::Array(a) => {
                    // Every element (no short-circuit).
                    let mut any = false;
                    for e in a.iter_mut() {
                        any |= scale(e, f);
                    }
                    any
                }
                _ => false,
            }
        }
        fn walk(path: &str, v: &mut toml::Value, f: f64, done: &mut Vec<String>) {
            let Some(t) = v.as_table_mut() else { return };
            for (k, v) in t.iter_mut() {
                let key = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                if key == "mcap" {
                    continue;
                }
                let factor = if k.ends_with("_m") {
                    f
                } else if k.ends_with("_m2") {
                    f * f
                } else {
                    walk(&key, v, f, done);
                    continue;
                };
                if scale(v, factor) {
                    done.push(key);
                }
            }
        }
        if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
            return Err(Error::Config(format!(
                "a length unit of {metres_per_unit} m"
            )));
        }
        let mut doc = self.document.clone();
        let mut done = Vec::new();
        walk("", &mut doc, metres_per_unit, &mut done);
        Ok((Config::from_document(doc)?, done))
    }

    /// Output point format override, `None` for "auto".
    pub fn output_point_format(&self) -> Result<Option<u8>> {
        match &self.output.point_format {
            toml::Value::String(s) if s == "auto" => Ok(None),
            toml::Value::String(s) => s
                .parse::<u8>()
                .ok()
                .filter(|n| *n <= 10)
                .map(Some)
                .ok_or_else(|| {
                    Error::Config(format!("output.point_format: '{s}' is not auto or 0..=10"))
                }),
            toml::Value::Integer(n) if (0..=10).contains(n) => Ok(Some(*n as u8)),
            other => Err(Error::Config(format!(
                "output.point_format: {other} is not \"auto\" or 0..=10"
            ))),
        }
    }

    fn validate(&self) -> Result<()> {
        let t = &self.tiling;
        if !(t.tile_size_m.is_finite() && t.tile_size_m > 0.0) {
            return Err(Error::Config(format!(
                "tiling.tile_size_m must be a positive number, got {}",
                t.tile_size_m
            )));
        }
        if !(t.buffer_m.is_finite() && t.buffer_m >= 0.0 && t.buffer_m < t.tile_size_m) {
            return Err(Error::Config(format!(
                "tiling.buffer_m must be in [0, tile_size_m), got {}",
                t.buffer_m
            )));
        }
        if !(t.dense_buffer_m.is_finite() && t.dense_buffer_m >= 0.0) {
            return Err(Error::Config("tiling.dense_buffer_m must be >= 0".into()));
        }
        if !(t.min_tile_size_m.is_finite() && t.min_tile_size_m > 0.0) {
            return Err(Error::Config(
                "tiling.min_tile_size_m must be positive".into(),
            ));
        }
        if self.pipeline.memory_budget_mb > crate::budget::MAX_BUDGET_BYTES >> 20 {
            return Err(Error::Config(format!(
                "pipeline.memory_budget_mb must be at most {} (1 PiB), got {}",
                crate::budget::MAX_BUDGET_BYTES >> 20,
                self.pipeline.memory_budget_mb
            )));
        }
        if self.pipeline.memory_budget_mb < 64 {
            return Err(Error::Config(format!(
                "pipeline.memory_budget_mb must be at least 64, got {}",
                self.pipeline.memory_budget_mb
            )));
        }
        if crate::io::output::Container::parse(&self.output.format).is_none() {
            return Err(Error::Config(format!(
                "output.format must be \"laz\", \"las\" or \"copc\", got \"{}\"",
                self.output.format
            )));
        }
        self.output_point_format()?;
        self.mcap.validate()?;
        self.stitch.validate().map_err(Error::Config)?;
        self.crs.stated_unit()?;
        // Every stage's own section (whether or not it runs) and the stage list.
        crate::stages::validate_stages(&self.stages.run, &self.sections)
    }

    /// The stages named in `stages.run`, in order, each built from its own section.
    pub fn build_stages(&self) -> Result<Vec<Box<dyn crate::stages::Stage>>> {
        crate::stages::build_stages(&self.stages.run, &self.sections)
    }

    /// The section of stage `name`, parsed into the stage's section type (e.g.
    /// [`crate::stages::ground::GroundSection`]).
    pub fn stage_section<T: serde::de::DeserializeOwned>(&self, name: &str) -> Result<T> {
        let raw = self
            .sections
            .get(name)
            .cloned()
            .unwrap_or_else(|| toml::Value::Table(toml::Table::new()));
        crate::stages::parse_section(name, &raw)
    }
}

/// Moves renamed keys of a user file to their new names.
fn rename_keys(user: &mut toml::Value, source: &str) -> Result<()> {
    for (old, new) in RENAMED {
        let (Some((section, old_key)), Some((_, new_key))) =
            (old.split_once('.'), new.split_once('.'))
        else {
            continue;
        };
        let Some(t) = user.get_mut(section).and_then(|v| v.as_table_mut()) else {
            continue;
        };
        if let Some(v) = t.remove(old_key) {
            if t.contains_key(new_key) {
                return Err(Error::Config(format!(
                    "{source}: both {old} and {new} are set; {old} is the old name of {new}"
                )));
            }
            tracing::warn!("{source}: {old} is now called {new}");
            t.insert(new_key.to_string(), v);
        }
    }
    Ok(())
}

/// A `--set` item with a renamed key written with its new name.
fn renamed_override(item: &str) -> String {
    if let Some((key, value)) = item.split_once('=') {
        if let Some((old, new)) = RENAMED.iter().find(|(old, _)| *old == key.trim()) {
            tracing::warn!("--set {old}: {old} is now called {new}");
            return format!("{new}={value}");
        }
    }
    item.to_string()
}

fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(existing) if existing.is_table() && v.is_table() => merge(existing, v),
                    _ => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

/// Applies `section.key=value`; the value is parsed as a TOML literal, else taken as a string.
fn apply_override(root: &mut toml::Value, item: &str) -> Result<()> {
    let (path, raw) = item
        .split_once('=')
        .ok_or_else(|| Error::Config(format!("--set '{item}': expected section.key=value")))?;
    let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let mut node = root;
    let parts: Vec<&str> = path.trim().split('.').collect();
    for (i, part) in parts.iter().enumerate() {
        let table = node
            .as_table_mut()
            .ok_or_else(|| Error::Config(format!("--set '{item}': '{part}' is not a section")))?;
        if i + 1 == parts.len() {
            if !table.contains_key(*part) {
                return Err(Error::Config(format!(
                    "--set '{item}': unknown key '{path}'"
                )));
            }
            table.insert((*part).to_string(), value);
            return Ok(());
        }
        node = table
            .get_mut(*part)
            .ok_or_else(|| Error::Config(format!("--set '{item}': unknown section '{part}'")))?;
    }
    Err(Error::Config(format!("--set '{item}': empty key")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn length_unit_converts_distances_and_areas_only() {
        let c = Config::defaults().unwrap();
        let (f, keys) = c.in_length_unit(0.5).unwrap();
        assert_eq!(f.tiling.tile_size_m, 2.0 * c.tiling.tile_size_m);
        assert_eq!(f.tiling.buffer_m, 2.0 * c.tiling.buffer_m);
        let g = |c: &Config, k: &str| c.effective[k].parse::<f64>().unwrap();
        for k in ["ground.params.max_distance_m", "segment.params.r_grow_m"] {
            assert_eq!(g(&f, k), 2.0 * g(&c, k), "{k}");
            assert!(keys.iter().any(|x| x == k), "{k}");
        }
        let area = "label.objects.roof_min_area_m2";
        assert_eq!(g(&f, area), 4.0 * g(&c, area));
        assert_eq!(f.effective["label.objects.vehicle_length_m"], "[5.0, 15.0]");
        // Angles, counts, colour distances and the MCAP decoding (always metres) stay.
        for k in [
            "ground.params.max_angle_deg",
            "segment.params.k",
            "segment.params.c_thg",
            "mcap.min_range_m",
            "mcap.scale_m",
            "pipeline.memory_budget_mb",
        ] {
            assert_eq!(f.effective[k], c.effective[k], "{k}");
            assert!(!keys.iter().any(|x| x == k), "{k}");
        }
        // The rule the conversion relies on: lengths are named *_m / *_m2 in the defaults.
        for (k, v) in &c.effective {
            let last = k.rsplit('.').next().unwrap();
            let numeric = v.parse::<f64>().is_ok() || v.starts_with('[');
            if numeric
                && (last.contains("dist") || last.contains("radius") || last.contains("size"))
            {
                assert!(
                    last.ends_with("_m")
                        || last.ends_with("_m2")
                        || last.ends_with("_mb")
                        || last.ends_with("_px"),
                    "{k} looks like a length but is not named *_m"
                );
            }
        }
        assert!(c.in_length_unit(0.0).is_err());
        assert!(Config::load(None, &["crs.units=\"yard\"".into()]).is_err());
    }

    #[test]
    fn defaults_parse_and_validate() {
        let c = Config::defaults().unwrap();
        assert_eq!(c.tiling.tile_size_m, 50.0);
        assert_eq!(c.pipeline.memory_budget_mb, 1024);
        assert_eq!(c.output_point_format().unwrap(), None);
    }

    #[test]
    fn ground_presets_in_config_match_the_library() {
        // config/ is the single source of defaults for runs; the library's constructors must
        // not drift from it (the ISPRS/KITTI gates test the library values).
        use crate::stages::ground::GroundSection;
        let c = Config::defaults().unwrap();
        let cg: GroundSection = c.stage_section("ground").unwrap();
        assert_eq!(cg.params, crate::ground::GroundParams::mobile());
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/airborne.toml");
        let a = Config::load(Some(&path), &[]).unwrap();
        let ag: GroundSection = a.stage_section("ground").unwrap();
        assert_eq!(ag.params, crate::ground::GroundParams::default());
        assert!(a.tiling.buffer_m >= ag.params.seed_cell_m);
        assert!(c.tiling.buffer_m >= cg.params.seed_cell_m);
    }

    #[test]
    fn overrides_apply_and_unknown_keys_fail() {
        let c = Config::load(
            None,
            &["tiling.tile_size_m=25".into(), "output.format=las".into()],
        )
        .unwrap();
        assert_eq!(c.tiling.tile_size_m, 25.0);
        assert_eq!(c.output.format, "las");
        assert!(Config::load(None, &["tiling.nope=1".into()]).is_err());
        assert!(Config::load(None, &["tiling.buffer_m=100".into()]).is_err());
        assert!(Config::load(None, &["output.point_format=12".into()]).is_err());
    }

    #[test]
    fn every_stage_section_is_checked_at_load_and_the_stage_list_too() {
        let err = |o: &[&str]| {
            let o: Vec<String> = o.iter().map(|s| s.to_string()).collect();
            Config::load(None, &o).unwrap_err().to_string()
        };
        // Sections of stages that do not run are still checked.
        let only_stats = "stages.run=[\"stats\"]";
        assert!(err(&[only_stats, "segment.context_m=-1"]).contains("segment.context_m"));
        assert!(err(&[only_stats, "label.context_m=-1"]).contains("label"));
        assert!(err(&[only_stats, "label.ground.context_m=nan"]).contains("ground.context_m"));
        assert!(err(&[only_stats, "ground.nonground_class=300"]).contains("nonground_class"));
        // The list: known names, once each, prerequisites first.
        assert!(err(&["stages.run=[\"grund\"]"]).contains("unknown stage \"grund\""));
        assert!(err(&["stages.run=[\"ground\", \"ground\"]"]).contains("twice"));
        assert!(err(&["stages.run=[\"label\"]"]).contains("needs \"ground\""));
        assert!(err(&["stages.run=[\"label\", \"ground\"]"]).contains("needs \"ground\""));
        assert!(err(&["stages.run=[]"]).contains("at least one"));
        // A stage's section rejects unknown keys and names itself.
        let file = std::env::temp_dir().join(format!("tessera-cfg-{}.toml", std::process::id()));
        std::fs::write(&file, "[segment.params]\nnope = 1\n").unwrap();
        let e = Config::load(Some(&file), &[]).unwrap_err().to_string();
        let _ = std::fs::remove_file(&file);
        assert!(e.contains("[segment]") && e.contains("nope"), "{e}");
        assert!(err(&["stages.run=[\"stats\"]", "bogus.x=1"]).contains("unknown"));
        // A wrong type deep in a section names the key.
        let e = err(&["label.ground.k=\"many\""]);
        assert!(e.contains("[label]") && e.contains("k"), "{e}");
    }

    #[test]
    fn renamed_keys_are_still_accepted() {
        use crate::stages::segment::SegmentSection;
        let c = Config::load(None, &["segment.buffer_m=3".into()]).unwrap();
        let s: SegmentSection = c.stage_section("segment").unwrap();
        assert_eq!(s.context_m, 3.0);
        let t = Config::load(
            None,
            &[
                "tiling.thin_split_buffers=false".into(),
                "tiling.split_dense_buffer_m=2".into(),
            ],
        )
        .unwrap()
        .tiling;
        assert!(!t.thin_far_buffers);
        assert_eq!(t.dense_buffer_m, 2.0);
        let dir = std::env::temp_dir().join(format!("tessera-ren-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("old.toml");
        std::fs::write(
            &file,
            "[segment]\nbuffer_m = 2.5\n[label]\nbuffer_m = 1.5\n",
        )
        .unwrap();
        let c = Config::load(Some(&file), &[]).unwrap();
        let s: SegmentSection = c.stage_section("segment").unwrap();
        assert_eq!(s.context_m, 2.5);
        let l: crate::stages::label::LabelSection = c.stage_section("label").unwrap();
        assert_eq!(l.context_m, 1.5);
        std::fs::write(&file, "[segment]\nbuffer_m = 2.5\ncontext_m = 4\n").unwrap();
        let e = Config::load(Some(&file), &[]).unwrap_err().to_string();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(
            e.contains("both segment.buffer_m and segment.context_m"),
            "{e}"
        );
        let ok = Config::load(None, &["stages.run=[\"ground\", \"label\"]".into()]);
        assert!(ok.is_ok());
    }
}
