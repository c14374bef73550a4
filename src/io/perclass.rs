//! Per-class outputs (`output.per_class`): one LAS/LAZ file per class code across all tiles —
//! the street-level document's end product (road, cycle path, footpath, grass, building,
//! vegetation, pole, vehicle, …). Filled from the records as the tiles are written (a
//! [`WrittenRecords`] observer, final segment ids included), staged, and committed with the
//! run's other outputs.

use crate::error::{Error, Result};
use crate::io::laswrite::LasFile;
use crate::io::output::{RecordFields, WrittenRecords};
use crate::io::workspace::OutputDir;
use las::PointDataBuilder;
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// One class file: what a run wrote (summary.json `class_files`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ClassFile {
    /// Class code.
    pub class: u8,
    /// Its name.
    pub name: String,
    /// File name in the output directory.
    pub file: String,
    /// Points in it.
    pub points: u64,
}

/// The per-class files of a run, open while tiles are written.
pub struct ClassFiles {
    header: las::Header,
    extension: &'static str,
    dir: PathBuf,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    writers: BTreeMap<u8, (LasFile, u64)>,
    tiles: HashSet<String>,
}

impl std::fmt::Debug for ClassFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClassFiles")
            .field("dir", &self.dir)
            .finish()
    }
}

/// Names of the per-class files a tessera output directory holds (its summary.json
/// `class_files`): derived from its tiles, so a walk reading the directory as input skips
/// them rather than read every point twice. Empty when `dir` is not an output directory.
pub fn derived_files(dir: &Path) -> std::collections::HashSet<String> {
    let mut names = std::collections::HashSet::new();
    if !crate::io::workspace::is_output_dir(dir) {
        return names;
    }
    let Ok(text) = std::fs::read_to_string(dir.join("summary.json")) else {
        return names;
    };
    let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else {
        return names;
    };
    for f in v["class_files"].as_array().into_iter().flatten() {
        if let Some(name) = f["file"].as_str() {
            names.insert(name.to_string());
        }
    }
    names
}

/// File name of class `code`: `class_011_road_surface.laz`.
pub fn file_name(code: u8, extension: &str) -> String {
    let name: String = crate::model::class_name(code)
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let mut name = name.replace("__", "_");
    while name.contains("__") {
        name = name.replace("__", "_");
    }
    format!("class_{code:03}_{}.{extension}", name.trim_matches('_'))
}

impl ClassFiles {
    /// Class files with the tiles' `header` (LAZ when `laz`), staged in `stage/classes`.
    pub fn new(header: &las::Header, laz: bool, stage: &Path) -> Result<ClassFiles> {
        let dir = stage.join("classes");
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        Ok(ClassFiles {
            header: header.clone(),
            extension: if laz { "laz" } else { "las" },
            dir,
            state: Mutex::new(State::default()),
        })
    }

    /// Adds the records of tile files the run did not write itself (tiles a resumed run
    /// reused, or tasks' tiles `tessera stitch` linked): `files` are (tile name, path).
    pub fn add_files(&self, files: &[(String, PathBuf)]) -> Result<()> {
        for (name, path) in files {
            if self.lock().tiles.contains(name) {
                continue;
            }
            crate::io::guard::check_path(path)?;
            let h = las::Reader::from_path(path)
                .map_err(|e| Error::las(path, e))?
                .header()
                .clone();
            if h.point_format() != self.header.point_format() {
                return Err(Error::bad_input(
                    path,
                    "its point format differs from this run's tiles; cannot add it to the per-class files",
                ));
            }
            let f = RecordFields::of_header(&h);
            let mut block = Vec::with_capacity(1 << 20);
            let mut res = Ok(());
            crate::io::output::for_each_record(path, &h, &f, false, &mut |rec| {
                block.extend_from_slice(rec);
                if block.len() >= 1 << 20 && res.is_ok() {
                    res = self.written(name, &f, &block);
                    block.clear();
                }
            })?;
            res?;
            self.written(name, &f, &block)?;
        }
        Ok(())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Closes the files and commits them into `out` (class order); returns what was written.
    pub fn finish(&self, out: &mut OutputDir) -> Result<Vec<ClassFile>> {
        let writers = std::mem::take(&mut self.lock().writers);
        let mut done = Vec::with_capacity(writers.len());
        let mut staged = Vec::with_capacity(writers.len());
        for (code, (w, points)) in writers {
            let file = file_name(code, self.extension);
            w.finish()?;
            staged.push((self.dir.join(&file), file.clone()));
            done.push(ClassFile {
                class: code,
                name: crate::model::class_name(code).to_string(),
                file,
                points,
            });
        }
        out.commit(&staged)?;
        let _ = std::fs::remove_dir(&self.dir);
        Ok(done)
    }
}

impl WrittenRecords for ClassFiles {
    fn written(&self, tile: &str, f: &RecordFields, records: &[u8]) -> Result<()> {
        // Bucket the block by class, then append each bucket to its file (one lock for the
        // block: files are appended in the order blocks arrive).
        let mut buckets: BTreeMap<u8, Vec<u8>> = BTreeMap::new();
        for rec in records.chunks_exact(f.record_len) {
            let class = rec[f.class_at] & f.class_mask;
            buckets.entry(class).or_default().extend_from_slice(rec);
        }
        let mut st = self.lock();
        if !st.tiles.contains(tile) {
            st.tiles.insert(tile.to_string());
        }
        for (code, bytes) in buckets {
            let n = (bytes.len() / f.record_len) as u64;
            let (w, count) = match st.writers.entry(code) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => {
                    let path = self.dir.join(file_name(code, self.extension));
                    // One thread appends at a time: sequential compression.
                    let opts =
                        las::WriterOptions::default().with_laz_parallelism(las::LazParallelism::No);
                    e.insert((LasFile::create(&path, self.header.clone(), opts)?, 0))
                }
            };
            let mut format = *self.header.point_format();
            format.is_compressed = false;
            let data = PointDataBuilder::new()
                .with_format(format)
                .with_transforms(*self.header.transforms())
                .build_from_bytes(bytes)
                .map_err(|e| Error::las(&self.dir, e))?;
            w.write_points(&data)?;
            *count += n;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn file_names_carry_code_and_name() {
        assert_eq!(super::file_name(11, "laz"), "class_011_road_surface.laz");
        assert_eq!(super::file_name(67, "las"), "class_067_grass_terrain.las");
        assert_eq!(super::file_name(200, "laz"), "class_200_user_class.laz");
    }
}
