//! Buffers: for random inputs and random tile/buffer sizes, each worker sees exactly the points
//! inside its core + buffer bounds, and every point is in exactly one core — also for tiles
//! the quadtree splits to fit a small memory budget.

use las::{Builder, Point, Transform, Vector, Writer};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use tessera::model::{RecordLayout, Rect, Tile};
use tessera::stages::{Stage, TileReport};
use tessera::Config;

/// What one tile saw: core rectangle, buffer width, point ids, core count.
type Seen = (Rect, f64, Vec<u64>, usize);

/// Records what every tile saw.
#[derive(Default)]
struct Recorder {
    seen: Mutex<Vec<Seen>>,
}

impl Stage for &'static Recorder {
    fn name(&self) -> &'static str {
        "recorder"
    }
    fn bytes_per_point(&self) -> usize {
        0
    }
    fn needs_context(&self) -> bool {
        true
    }
    fn process(
        &self,
        tile: &mut Tile,
        _: &RecordLayout,
        _: &mut TileReport,
    ) -> tessera::Result<()> {
        self.seen
            .lock()
            .unwrap()
            .push((tile.core, tile.buffer_m, tile.ids.clone(), tile.n_core));
        Ok(())
    }
}

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Writes `n` points around (cx, cy); half of them in a dense blob so splits happen.
fn write_random(
    path: &Path,
    rng: &mut Lcg,
    n: usize,
    cx: f64,
    cy: f64,
    extent: f64,
) -> Vec<[f64; 3]> {
    let mut b = Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    b.transforms = Vector {
        x: Transform {
            scale: 0.001,
            offset: 1000.0,
        },
        y: Transform {
            scale: 0.001,
            offset: 2000.0,
        },
        z: Transform {
            scale: 0.001,
            offset: 0.0,
        },
    };
    let mut w = Writer::from_path(path, b.into_header().unwrap()).unwrap();
    let mut pts = Vec::new();
    for i in 0..n {
        let (x, y) = if i % 2 == 0 {
            (cx + rng.next() * extent, cy + rng.next() * extent)
        } else {
            (
                cx + 0.3 * extent + rng.next() * 0.05 * extent,
                cy + 0.6 * extent + rng.next() * 0.05 * extent,
            )
        };
        let x = (x * 1000.0).round() / 1000.0;
        let y = (y * 1000.0).round() / 1000.0;
        let z = (rng.next() * 10_000.0).round() / 1000.0;
        w.write_point(Point {
            x,
            y,
            z,
            gps_time: Some(i as f64),
            ..Default::default()
        })
        .unwrap();
        pts.push([x, y, z]);
    }
    w.close().unwrap();
    pts
}

fn check(seed: u64, budget_mb: u64, n_per_file: usize) {
    let mut rng = Lcg(seed);
    let dir = tempfile::tempdir().unwrap();
    let mut files: Vec<PathBuf> = Vec::new();
    let mut all: HashMap<u64, [f64; 3]> = HashMap::new();
    for f in 0..3 {
        let p = dir.path().join(format!("in{f}.las"));
        let (cx, cy) = (1000.0 + 40.0 * rng.next(), 2000.0 + 40.0 * rng.next());
        let pts = write_random(&p, &mut rng, n_per_file, cx, cy, 60.0);
        files.push(p);
        // Inputs are sorted by path, so file index = f.
        for (i, q) in pts.into_iter().enumerate() {
            all.insert(((f as u64) << 40) | i as u64, q);
        }
    }
    let tile = 5.0 + 40.0 * rng.next();
    let buffer = tile * 0.45 * rng.next();
    let cfg = Config::load(
        None,
        &[
            format!("tiling.tile_size_m={tile}"),
            format!("tiling.buffer_m={buffer}"),
            format!("pipeline.memory_budget_mb={budget_mb}"),
            "tiling.min_tile_size_m=0.05".into(),
            // Four workers share the budget: ~60 k points per tile at 64 MiB.
            format!("pipeline.threads={}", if budget_mb <= 64 { 4 } else { 2 }),
        ],
    )
    .unwrap();
    let rec: &'static Recorder = Box::leak(Box::default());
    let stages: Vec<Box<dyn Stage>> = vec![Box::new(rec)];
    let out = dir.path().join("out");
    let s = tessera::pipeline::run_with_stages(&files, &out, &cfg, &stages, &|_, _| {}).unwrap();
    let seen = rec.seen.lock().unwrap();
    let mut core_count: HashMap<u64, u32> = HashMap::new();
    for (core, b, ids, n_core) in seen.iter() {
        let region = core.expanded(*b);
        let mut got_core: Vec<u64> = ids[..*n_core].to_vec();
        let mut got_buf: Vec<u64> = ids[*n_core..].to_vec();
        let mut want_core: Vec<u64> = Vec::new();
        let mut want_buf: Vec<u64> = Vec::new();
        for (id, p) in &all {
            if core.contains(p[0], p[1]) {
                want_core.push(*id);
            } else if region.contains(p[0], p[1]) {
                want_buf.push(*id);
            }
        }
        for v in [&mut got_core, &mut got_buf, &mut want_core, &mut want_buf] {
            v.sort();
        }
        assert_eq!(
            got_core, want_core,
            "core of {core:?} (tile {tile}, buffer {buffer})"
        );
        assert_eq!(
            got_buf, want_buf,
            "buffer of {core:?} (tile {tile}, buffer {buffer})"
        );
        for id in got_core {
            *core_count.entry(id).or_default() += 1;
        }
    }
    assert_eq!(core_count.len(), all.len(), "every point in a core");
    assert!(
        core_count.values().all(|c| *c == 1),
        "no point in two cores"
    );
    assert_eq!(s.points_out, all.len() as u64);
    if budget_mb <= 64 {
        assert!(
            s.tiles_split > 0,
            "expected quadtree splits at {budget_mb} MiB"
        );
    }
}

#[test]
fn random_tiles_see_exactly_their_core_and_buffer() {
    for seed in 1..=6 {
        check(seed, 1024, 20_000);
    }
}

#[test]
fn split_tiles_keep_exact_buffers() {
    // 64 MiB with four workers leaves ~60 k points per tile: the dense blobs must be split.
    for seed in 11..=13 {
        check(seed, 64, 100_000);
    }
}

/// Slow stage that fails on the fifth tile it sees.
struct SlowFailing(std::sync::atomic::AtomicUsize);

impl Stage for SlowFailing {
    fn name(&self) -> &'static str {
        "slow_failing"
    }
    fn bytes_per_point(&self) -> usize {
        0
    }
    fn process(
        &self,
        tile: &mut Tile,
        _: &RecordLayout,
        _: &mut TileReport,
    ) -> tessera::Result<()> {
        std::thread::sleep(std::time::Duration::from_millis(30));
        if self.0.fetch_add(1, std::sync::atomic::Ordering::SeqCst) == 4 {
            return Err(tessera::Error::Stage {
                tile: tile.name.to_string(),
                stage: "slow_failing",
                source: "injected".into(),
            });
        }
        Ok(())
    }
}

#[test]
fn stage_failure_while_reader_and_tiler_are_blocked_does_not_hang() {
    // 60 small inputs, one per tile: tiles are released while reading, the slow workers fill
    // the job queue, the tiler blocks on it and the reader on the chunk queue. A failing stage
    // must still end the run with its error (it used to leave the reader blocked forever).
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Lcg(99);
    let mut files = Vec::new();
    for f in 0..60 {
        let p = dir.path().join(format!("f{f:02}.las"));
        let (cx, cy) = (
            1000.0 + 100.0 * (f % 8) as f64,
            2000.0 + 100.0 * (f / 8) as f64,
        );
        write_random(&p, &mut rng, 30_000, cx + 10.0, cy + 10.0, 30.0);
        files.push(p);
    }
    let cfg = Config::load(
        None,
        &[
            "tiling.tile_size_m=100".into(),
            "tiling.buffer_m=0".into(),
            "pipeline.memory_budget_mb=64".into(),
        ],
    )
    .unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let out = dir.path().join("out");
    std::thread::spawn(move || {
        let stages: Vec<Box<dyn Stage>> = vec![Box::new(SlowFailing(Default::default()))];
        let r = tessera::pipeline::run_with_stages(&files, &out, &cfg, &stages, &|_, _| {});
        let _ = tx.send(r.map(|_| ()).map_err(|e| e.to_string()));
    });
    match rx.recv_timeout(std::time::Duration::from_secs(60)) {
        Ok(Err(e)) => assert!(e.contains("injected"), "{e}"),
        Ok(Ok(())) => panic!("the injected failure was lost"),
        Err(_) => panic!("pipeline hung after a stage error"),
    }
}
