//! The trained classifier of the labelling stage: the class-map file that translates a
//! reference's codes (SemanticKITTI ids, a producer's classes) into tessera codes, the model
//! file `tessera train` writes and `label.model` names, and the sample collector that
//! training runs inside the pipeline (so training features are computed exactly as the
//! labelling stage computes them at run time: same tiles, same context, same rules).

use super::descriptors;
use super::forest::{Forest, ForestParams};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;

/// One class of a class map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassEntry {
    /// The tessera code (what the labelling stage writes).
    pub code: u8,
    /// A name for tables.
    #[serde(default)]
    pub name: String,
    /// Reference codes that mean this class.
    pub reference: Vec<u32>,
}

/// A class map: reference codes → tessera codes (e.g. `config/semantickitti.toml`).
/// Reference codes not listed are not scored and not trained on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassMap {
    /// What the reference is.
    #[serde(default)]
    pub name: String,
    /// The attribute holding the reference codes in training files (`classification` or an
    /// extra-bytes name such as the synthetic scenes' `gt_class`).
    #[serde(default = "default_field")]
    pub field: String,
    /// The classes.
    #[serde(rename = "class")]
    pub classes: Vec<ClassEntry>,
}

fn default_field() -> String {
    "classification".into()
}

impl ClassMap {
    /// Reads and checks a class-map TOML file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::io::files::read_text_bounded(path, 1 << 20)?;
        let m: ClassMap = toml::from_str(&text)
            .map_err(|e| Error::Config(format!("{}: not a class map: {e}", path.display())))?;
        let mut seen = BTreeMap::new();
        for c in &m.classes {
            if c.code == 0 {
                return Err(Error::Config(format!(
                    "{}: class {:?}: code 0 is reserved for \"not scored\"",
                    path.display(),
                    c.name
                )));
            }
            for &r in &c.reference {
                if let Some(other) = seen.insert(r, c.code) {
                    if other != c.code {
                        return Err(Error::Config(format!(
                            "{}: reference code {r} is mapped to both {other} and {}",
                            path.display(),
                            c.code
                        )));
                    }
                }
            }
        }
        if m.classes.is_empty() {
            return Err(Error::Config(format!("{}: no [[class]]", path.display())));
        }
        Ok(m)
    }

    /// The tessera code of a reference code (0: not mapped).
    pub fn code_of(&self, reference: u32) -> u8 {
        self.classes
            .iter()
            .find(|c| c.reference.contains(&reference))
            .map_or(0, |c| c.code)
    }

    /// The tessera codes, in file order, without repeats.
    pub fn codes(&self) -> Vec<u8> {
        let mut v: Vec<u8> = Vec::new();
        for c in &self.classes {
            if !v.contains(&c.code) {
                v.push(c.code);
            }
        }
        v
    }
}

/// The model file's format tag.
pub const FORMAT: &str = "tessera-forest/1";

/// A trained labelling model (JSON).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Model {
    /// [`FORMAT`].
    pub format: String,
    /// Feature names at training time; must equal [`descriptors::feature_names`].
    pub features: Vec<String>,
    /// tessera code of each class index.
    pub classes: Vec<u8>,
    /// Whether a class is a ground class (most of its training points were ground by the
    /// ground filter): ground points get a ground class, other points one of the others.
    pub ground: Vec<bool>,
    /// Training points per class.
    pub samples: Vec<usize>,
    /// The files it was trained on.
    pub trained_on: Vec<String>,
    /// Training parameters.
    pub params: ForestParams,
    /// The forest.
    pub forest: Forest,
}

impl Model {
    /// Loads a model and checks it was trained with this version's features.
    pub fn load(path: &Path) -> Result<Model> {
        let text = crate::io::files::read_text_bounded(path, 1 << 30)?;
        let mut m: Model = serde_json::from_str(&text)
            .map_err(|e| Error::bad_input(path, format!("not a tessera model: {e}")))?;
        if m.format != FORMAT {
            return Err(Error::bad_input(
                path,
                format!("model format {:?}, expected {FORMAT:?}", m.format),
            ));
        }
        if m.features != descriptors::feature_names() {
            return Err(Error::bad_input(
                path,
                "the model was trained on other features (another tessera version): train it again",
            ));
        }
        let c = m.classes.len();
        if c == 0
            || m.ground.len() != c
            || m.forest.classes != c
            || m.forest.features != m.features.len()
        {
            return Err(Error::bad_input(
                path,
                "inconsistent model (class or feature counts)",
            ));
        }
        m.forest = m.forest.checked().map_err(|e| Error::bad_input(path, e))?;
        Ok(m)
    }

    /// Writes the model (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string(self).map_err(|e| Error::Internal(e.to_string()))?;
        crate::io::output::write_atomic(path, text.as_bytes())
    }

    /// Allowed class indices for ground and for non-ground points.
    pub fn allowed(&self) -> [Vec<bool>; 2] {
        [
            self.ground.clone(),
            self.ground.iter().map(|g| !g).collect(),
        ]
    }
}

/// Training samples gathered while the pipeline runs: per tessera code, the points with the
/// smallest hashes of their global ids (a bottom-k sample: the same points whatever the
/// order in which tiles finish).
pub struct Collector {
    /// tessera code per input file and point (0: not trained on), and the number of the
    /// run they belong to (training runs the pipeline once per file set).
    refs: std::sync::RwLock<(u64, Vec<Vec<u8>>)>,
    cap: usize,
    rows: Mutex<BTreeMap<u8, Vec<Row>>>,
}

impl std::fmt::Debug for Collector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Collector {{ cap: {} }}", self.cap)
    }
}

struct Row {
    key: u64,
    ground: bool,
    x: Vec<f32>,
}

/// A well-mixed hash of a point id: the first output of SplitMix64 seeded with it.
fn mix(id: u64) -> u64 {
    crate::rng::Rng(id).next()
}

/// Samples per class ready for [`Forest::train`].
pub struct TrainingSet {
    /// Row-major features.
    pub x: Vec<f32>,
    /// Class index per row.
    pub y: Vec<u16>,
    /// tessera code per class index.
    pub classes: Vec<u8>,
    /// Ground class flags.
    pub ground: Vec<bool>,
    /// Rows per class.
    pub samples: Vec<usize>,
}

impl Collector {
    /// At most `cap` points are kept per class.
    pub fn new(cap: usize) -> Self {
        Collector {
            refs: std::sync::RwLock::new((0, Vec::new())),
            cap: cap.max(1),
            rows: Mutex::new(BTreeMap::new()),
        }
    }

    /// Before pipeline run number `run`: `refs[file][point]` is the tessera code of each of
    /// its input points (0: skip).
    pub fn set_refs(&self, run: u64, refs: Vec<Vec<u8>>) {
        *self.refs.write().unwrap_or_else(|e| e.into_inner()) = (run, refs);
    }

    /// The tessera code of a global point id of the current run (0: skip).
    pub fn code_of(&self, id: u64) -> u8 {
        let (file, point) = (crate::model::file_of(id), (id & ((1 << 40) - 1)) as usize);
        let r = self.refs.read().unwrap_or_else(|e| e.into_inner());
        r.1.get(file)
            .and_then(|r| r.get(point))
            .copied()
            .unwrap_or(0)
    }

    /// Adds one point's features.
    pub fn add(&self, code: u8, id: u64, ground: bool, x: &[f32]) {
        let run = self.refs.read().unwrap_or_else(|e| e.into_inner()).0;
        let key = mix(id ^ run.rotate_right(16));
        let mut rows = self.rows.lock().unwrap_or_else(|e| e.into_inner());
        let v = rows.entry(code).or_default();
        v.push(Row {
            key,
            ground,
            x: x.to_vec(),
        });
        if v.len() >= 2 * self.cap {
            v.sort_unstable_by_key(|r| r.key);
            v.truncate(self.cap);
        }
    }

    /// The collected samples.
    pub fn finish(self) -> TrainingSet {
        let rows = self.rows.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut t = TrainingSet {
            x: Vec::new(),
            y: Vec::new(),
            classes: Vec::new(),
            ground: Vec::new(),
            samples: Vec::new(),
        };
        for (code, mut v) in rows {
            v.sort_unstable_by_key(|r| r.key);
            v.truncate(self.cap);
            let k = t.classes.len() as u16;
            t.classes.push(code);
            t.ground
                .push(2 * v.iter().filter(|r| r.ground).count() > v.len());
            t.samples.push(v.len());
            for r in v {
                t.x.extend_from_slice(&r.x);
                t.y.push(k);
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_map_reads_and_refuses_conflicts() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.toml");
        std::fs::write(
            &p,
            "name = \"t\"\n[[class]]\ncode = 6\nreference = [13]\n[[class]]\ncode = 5\nreference = [15, 16]\n",
        )
        .unwrap();
        let m = ClassMap::load(&p).unwrap();
        assert_eq!((m.code_of(13), m.code_of(16), m.code_of(1)), (6, 5, 0));
        assert_eq!(m.codes(), vec![6, 5]);
        std::fs::write(
            &p,
            "[[class]]\ncode = 6\nreference = [13]\n[[class]]\ncode = 5\nreference = [13]\n",
        )
        .unwrap();
        assert!(ClassMap::load(&p).is_err());
    }

    #[test]
    fn damaged_model_files_are_errors() {
        use crate::label::forest::{Forest, ForestParams};
        let dir = tempfile::tempdir().unwrap();
        let nf = descriptors::feature_count();
        // A tiny valid model: two classes split on feature 0.
        let mut x = vec![0.0f32; 40 * nf];
        let y: Vec<u16> = (0..40).map(|i| (i % 2) as u16).collect();
        for i in 0..40 {
            x[i * nf] = (i % 2) as f32;
        }
        let p = ForestParams {
            trees: 2,
            per_class: 20,
            ..Default::default()
        };
        let m = Model {
            format: FORMAT.into(),
            features: descriptors::feature_names(),
            classes: vec![6, 5],
            ground: vec![false, false],
            samples: vec![20, 20],
            trained_on: vec![],
            params: p.clone(),
            forest: Forest::train(&x, &y, nf, 2, &p),
        };
        let path = dir.path().join("m.json");
        m.save(&path).unwrap();
        assert!(Model::load(&path).is_ok());
        let text = std::fs::read_to_string(&path).unwrap();
        let cases = [
            ("truncated", text[..text.len() / 2].to_string()),
            ("format", text.replace(FORMAT, "tessera-forest/0")),
            ("features", text.replacen("s0.1_occupancy", "s0.1_other", 1)),
            // A split pointing back to the root would loop forever.
            ("loop", text.replacen("\"left\":[1,", "\"left\":[0,", 1)),
        ];
        for (what, t) in cases {
            std::fs::write(&path, &t).unwrap();
            let e = Model::load(&path).expect_err(what).to_string();
            assert!(e.contains("m.json"), "{what}: {e}");
        }
    }

    #[test]
    fn collector_keeps_the_same_points_in_any_order() {
        let run = |rev: bool| {
            let c = Collector::new(50);
            c.set_refs(0, vec![vec![6u8; 1000]]);
            let mut ids: Vec<u64> = (0..1000).collect();
            if rev {
                ids.reverse();
            }
            for id in ids {
                c.add(6, id, false, &[id as f32]);
            }
            c.finish().x
        };
        let a = run(false);
        assert_eq!(a.len(), 50);
        assert_eq!(a, run(true));
    }
}
