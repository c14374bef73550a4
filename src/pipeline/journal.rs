//! The resume journal: what a run has finished, durable, so that a run interrupted in any way
//! (SIGKILL, power loss, a full disk) is continued by the same command instead of redone.
//!
//! It lives in the output directory's resume directory ([`RESUME_DIR`], owned by the
//! [`OutputDir`]):
//! - `run.json` — the run's [`Fingerprint`]: tessera version, every effective setting, each
//!   input's path, size, modification time and header digest, and the grid. A resumed run
//!   must have the same fingerprint, or it is refused with the differences named.
//! - `log` — append-only JSON lines, each fsync'd before the run goes on: one [`Entry::Cell`]
//!   per grid cell whose every leaf tile is finished (its tiles' books and where their
//!   results are), and with stitching one [`Entry::Final`] per tile written with its global
//!   ids. A line cut short by a crash is ignored (its cell is simply redone).
//! - `parts/` — with stitching, each finished tile's core records with local segment ids,
//!   its segment table and its border summary, flushed to the disk before the cell's line.
//!
//! Why per cell: the tiler releases whole cells and a worker splits a cell into leaves
//! deterministically, so a cell is the unit that can be skipped without changing anything
//! downstream. On resume everything is read and tiled again (that is what tells the stitcher
//! which cells neighbour which, in the same order), journaled cells skip the stages and hand
//! their recorded results on, and the stitcher rebuilds its state from the recorded border
//! summaries. The outputs are those of an uninterrupted run, byte for byte.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::workspace::{OutputDir, RESUME_DIR};
use crate::model::CellKey;
use crate::report::FailedTile;
use crate::stages::TileReport;
use crate::tiling::Grid;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Settings that do not change what a run writes: a resumed run may differ in them.
pub const NOT_IN_FINGERPRINT: &[&str] = &[
    "output.overwrite",
    "output.restart",
    "pipeline.keep_going",
    "pipeline.spill_dir",
];

/// One input as the journal knows it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputStamp {
    /// Path as given.
    pub path: String,
    /// Size in bytes.
    pub size: u64,
    /// Modification time, nanoseconds since the epoch.
    pub mtime_ns: i64,
    /// FNV-1a digest of the file's first 4 KiB (its header and, for LAZ, its VLRs), hex.
    pub header_digest: String,
}

impl InputStamp {
    /// Stamps the file at `path`. An unreadable file (a `keep_going` run skips it) is
    /// stamped as such, with the error's kind.
    pub fn of(path: &Path) -> InputStamp {
        use std::io::Read;
        use std::os::unix::fs::MetadataExt;
        let m = std::fs::metadata(path).ok();
        let mut head = Vec::with_capacity(4096);
        let digest = match File::open(path).and_then(|f| f.take(4096).read_to_end(&mut head)) {
            Ok(_) => format!("{:016x}", fnv1a(&head)),
            Err(e) => format!("unreadable: {:?}", e.kind()),
        };
        InputStamp {
            path: path.display().to_string(),
            size: m.as_ref().map_or(0, |m| m.len()),
            mtime_ns: m.map_or(0, |m| m.mtime() * 1_000_000_000 + m.mtime_nsec()),
            header_digest: digest,
        }
    }
}

/// FNV-1a, 64 bits: a fixed, documented digest (unlike `DefaultHasher`, whose algorithm may
/// change between Rust versions).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// What makes two runs the same run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// tessera version.
    pub version: String,
    /// Effective settings (`section.key` → TOML value), except [`NOT_IN_FINGERPRINT`].
    pub config: BTreeMap<String, String>,
    /// The inputs as given (MCAP drives, not their decoded parts), in input order.
    pub inputs: Vec<InputStamp>,
    /// Tile size and buffer.
    pub grid: String,
}

impl Fingerprint {
    /// The fingerprint of a run of `inputs` under `cfg` on `grid`.
    pub fn of(cfg: &Config, inputs: &[PathBuf], grid: &Grid) -> Fingerprint {
        let mut config = cfg.effective.clone();
        config.retain(|k, _| !NOT_IN_FINGERPRINT.contains(&k.as_str()));
        Fingerprint {
            version: env!("CARGO_PKG_VERSION").to_string(),
            config,
            inputs: inputs.iter().map(|p| InputStamp::of(p)).collect(),
            grid: format!("tile {} m, buffer {} m", grid.tile_size_m, grid.buffer_m),
        }
    }

    /// What differs from `old`, one line each (at most a few of each kind, then a count).
    pub fn differences(&self, old: &Fingerprint) -> Vec<String> {
        let mut d = Vec::new();
        if self.version != old.version {
            d.push(format!(
                "tessera version {} → {}",
                old.version, self.version
            ));
        }
        let keys: std::collections::BTreeSet<&String> =
            self.config.keys().chain(old.config.keys()).collect();
        let none = "(unset)".to_string();
        for k in keys {
            let (a, b) = (
                old.config.get(k).unwrap_or(&none),
                self.config.get(k).unwrap_or(&none),
            );
            if a != b {
                d.push(format!("setting {k}: {a} → {b}"));
            }
        }
        let old_in: HashMap<&str, &InputStamp> =
            old.inputs.iter().map(|s| (s.path.as_str(), s)).collect();
        let new_in: HashMap<&str, &InputStamp> =
            self.inputs.iter().map(|s| (s.path.as_str(), s)).collect();
        for s in &self.inputs {
            match old_in.get(s.path.as_str()) {
                None => d.push(format!("input {} is new", s.path)),
                Some(o) if o.size != s.size => d.push(format!(
                    "input {} changed size ({} → {} bytes)",
                    s.path, o.size, s.size
                )),
                Some(o) if o.header_digest != s.header_digest => {
                    d.push(format!("input {} has a different header", s.path))
                }
                Some(o) if o.mtime_ns != s.mtime_ns => {
                    d.push(format!("input {} was modified since", s.path))
                }
                Some(_) => {}
            }
        }
        for s in &old.inputs {
            if !new_in.contains_key(s.path.as_str()) {
                d.push(format!("input {} is gone", s.path));
            }
        }
        if d.is_empty() && self.inputs != old.inputs {
            d.push("the inputs are listed in another order".into());
        }
        if self.grid != old.grid {
            d.push(format!("grid {} → {}", old.grid, self.grid));
        }
        const SHOW: usize = 8;
        if d.len() > SHOW {
            let more = d.len() - SHOW;
            d.truncate(SHOW);
            d.push(format!("and {more} more differences"));
        }
        d
    }
}

/// Where a finished tile's result is.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TileResult {
    /// Written into the output directory: these files, the point file first.
    Written {
        /// File names in the output directory.
        files: Vec<String>,
    },
    /// Deferred for stitching: `parts/NAME.stitch`, `NAME.segments.part`, `NAME.summary`.
    Deferred {
        /// Core points in the records file.
        points: usize,
    },
}

/// A finished tile's books.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TileEntry {
    /// Tile name.
    pub name: String,
    /// Core points.
    pub n_core: u64,
    /// Buffer points it was processed with.
    pub buffer_points: u64,
    /// Its stages' report.
    pub report: TileReport,
    /// The grid tile it was split from, if split.
    pub split_root: Option<String>,
    /// Far buffer copies its split dropped.
    pub buffer_thinned: u64,
    /// Its result.
    pub result: TileResult,
}

/// A tile a `keep_going` run left out.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FailedEntry {
    /// The tile and why.
    pub failed: FailedTile,
    /// The grid tile it was split from, if split.
    pub split_root: Option<String>,
    /// Far buffer copies its split dropped.
    pub buffer_thinned: u64,
}

/// One line of the log.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "entry", rename_all = "snake_case")]
pub enum Entry {
    /// Every leaf of a grid cell finished.
    Cell {
        /// Grid column.
        ix: i64,
        /// Grid row.
        iy: i64,
        /// Its tiles, in the order they finished.
        tiles: Vec<TileEntry>,
        /// Its tiles that failed (`keep_going`).
        failed: Vec<FailedEntry>,
    },
    /// A deferred tile was written with its global ids: these files.
    Final {
        /// Tile name.
        name: String,
        /// File names in the output directory.
        files: Vec<String>,
    },
}

/// What an earlier, interrupted run of the same fingerprint finished.
#[derive(Debug, Default)]
pub struct ResumeState {
    /// Finished cells: their tiles and failed tiles.
    pub cells: HashMap<CellKey, (Vec<TileEntry>, Vec<FailedEntry>)>,
    /// Deferred tiles already written with global ids, and their files.
    pub finals: HashMap<String, Vec<String>>,
    /// Where the journal keeps deferred tiles.
    pub parts: PathBuf,
}

impl ResumeState {
    /// Output files the earlier run committed that stay (everything else it committed is
    /// removed and written again).
    pub fn kept_files(&self) -> HashSet<String> {
        let mut keep: HashSet<String> = self.finals.values().flatten().cloned().collect();
        for (tiles, _) in self.cells.values() {
            for t in tiles {
                if let TileResult::Written { files } = &t.result {
                    keep.extend(files.iter().cloned());
                }
            }
        }
        keep
    }

    /// Tiles recorded as finished.
    pub fn tiles(&self) -> usize {
        self.cells.values().map(|(t, _)| t.len()).sum()
    }
}

/// The journal a run appends to.
#[derive(Debug)]
pub struct Journal {
    log: File,
    path: PathBuf,
    parts: PathBuf,
}

/// Paths of a deferred tile's files in `parts`: records, segment table, border summary.
pub fn part_files(parts: &Path, name: &str) -> [PathBuf; 3] {
    [
        parts.join(format!("{name}.stitch")),
        parts.join(format!("{name}.segments.part")),
        parts.join(format!("{name}.summary")),
    ]
}

impl Journal {
    /// Where deferred tiles go.
    pub fn parts(&self) -> &Path {
        &self.parts
    }

    /// Appends `e` and flushes it to the disk.
    pub fn append(&mut self, e: &Entry) -> Result<()> {
        let mut line = serde_json::to_vec(e).map_err(|e| Error::Internal(e.to_string()))?;
        line.push(b'\n');
        self.log
            .write_all(&line)
            .and_then(|_| self.log.sync_data())
            .map_err(|e| Error::io(&self.path, e))
    }
}

/// Reads a journal's log (`parts`: its parts directory).
pub fn read_log(path: &Path, parts: PathBuf) -> Result<ResumeState> {
    let text = match std::fs::read(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(Error::io(path, e)),
    };
    let mut st = ResumeState {
        parts,
        ..Default::default()
    };
    let lines: Vec<&[u8]> = text.split(|&b| b == b'\n').collect();
    for (i, line) in lines.iter().enumerate() {
        if line.is_empty() {
            continue;
        }
        let entry: Entry = match serde_json::from_slice(line) {
            Ok(e) => e,
            // The last line may be cut short by the crash; anything else is damage.
            Err(_) if i + 1 == lines.len() => break,
            Err(e) => {
                return Err(Error::OutputDir {
                    path: path.to_path_buf(),
                    reason: format!(
                    "line {} of the resume journal is damaged ({e}); pass --restart to start over",
                    i + 1
                ),
                    usage: false,
                })
            }
        };
        match entry {
            Entry::Cell {
                ix,
                iy,
                tiles,
                failed,
            } => {
                st.cells.insert((ix, iy), (tiles, failed));
            }
            Entry::Final { name, files } => {
                st.finals.insert(name, files);
            }
        }
    }
    Ok(st)
}

/// Starts the run's journal in `out`: continues an interrupted run with the same
/// fingerprint (returning what it finished) unless `restart`, or starts a fresh one. An
/// interrupted run with another fingerprint is refused with the differences, unless
/// `restart` or `overwrite` (which replaces an earlier run's outputs in any case).
pub fn start(
    out: &mut OutputDir,
    fp: &Fingerprint,
    restart: bool,
    overwrite: bool,
) -> Result<(Journal, Option<ResumeState>)> {
    let dir = out.path().join(RESUME_DIR);
    let run_json = dir.join("run.json");
    let log_path = dir.join("log");
    let parts = dir.join("parts");
    let mut resume = None;
    // A finished run removes its resume directory; one left behind by a run killed right
    // after it finished is stale.
    if !out.previous_finished() && run_json.is_file() {
        let old: Option<Fingerprint> = std::fs::read(&run_json)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok());
        let diff = match &old {
            Some(old) => fp.differences(old),
            None => vec!["its run.json is unreadable".into()],
        };
        if diff.is_empty() && !restart {
            let st = read_log(&log_path, parts.clone())?;
            out.adopt_previous(&st.kept_files())?;
            tracing::info!(
                "resuming the interrupted run in {}: {} cells ({} tiles) are finished",
                out.path().display(),
                st.cells.len(),
                st.tiles()
            );
            resume = Some(st);
        } else if !(restart || overwrite) {
            return Err(Error::OutputDir {
                path: out.path().to_path_buf(),
                reason: format!(
                    "holds the partial outputs of an earlier run that did not finish, and this run is not the same run, so it cannot be resumed: {}. Run the same command to resume it, or pass --restart to start over",
                    diff.join("; ")
                ),
                usage: true,
            });
        }
    }
    if resume.is_none() {
        out.fresh_resume_dir()?;
        let bytes = serde_json::to_vec_pretty(fp).map_err(|e| Error::Internal(e.to_string()))?;
        crate::io::output::write_atomic(&run_json, &bytes)?;
        crate::io::output::sync_file(&run_json)?;
    }
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|e| Error::io(&log_path, e))?;
    // A line cut short by the crash is cut off, so the next entry starts a line of its own.
    let bytes = std::fs::read(&log_path).map_err(|e| Error::io(&log_path, e))?;
    if bytes.last().is_some_and(|&b| b != b'\n') {
        let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        log.set_len(keep as u64)
            .map_err(|e| Error::io(&log_path, e))?;
    }
    let j = Journal {
        log,
        path: log_path,
        parts,
    };
    Ok((j, resume))
}
