//! Micro-benchmarks of the tiling hot path (fixed seed, 200 k points, small enough for a
//! 2-core machine): binning + spill buffering throughput at two buffer widths, against a
//! baseline that only decodes coordinates, measured in the same run.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use las::point::Format;
use las::{Transform, Vector};
use tessera::io::InputFile;
use tessera::model::{RecordLayout, Rect};
use tessera::tiling::{Grid, Tiler};

fn records(n: usize, layout: &RecordLayout) -> Vec<u8> {
    let mut out = vec![0u8; n * layout.record_len];
    let mut s = 12345u64;
    for rec in out.chunks_exact_mut(layout.record_len) {
        for k in 0..3 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            // A 200 m × 200 m area at 1 mm resolution; z up to 20 m.
            let v = ((s >> 33) % if k < 2 { 200_000 } else { 20_000 }) as i32;
            rec[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn bench_tiler(c: &mut Criterion) {
    let t = Transform {
        scale: 0.001,
        offset: 0.0,
    };
    let layout = RecordLayout::new(Format::new(1).unwrap(), Vector { x: t, y: t, z: t });
    let n = 200_000;
    let recs = records(n, &layout);
    let file = InputFile {
        path: "bench".into(),
        index: 0,
        header: las::Header::default(),
        points: n as u64,
        bounds: Rect {
            x0: 0.0,
            y0: 0.0,
            x1: 200.0,
            y1: 200.0,
        },
    };
    let files = vec![file];
    let dir = tempfile::tempdir().unwrap();
    let mut g = c.benchmark_group("tiler");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(20);
    g.bench_function("baseline_decode_xyz", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for rec in recs.chunks_exact(layout.record_len) {
                let p = layout.xyz(rec);
                acc += p[0] + p[1];
            }
            acc
        })
    });
    for buffer_m in [0.0, 5.0] {
        g.bench_function(format!("bin_spill_tile50_buffer{buffer_m}"), |b| {
            b.iter(|| {
                let grid = Grid {
                    tile_size_m: 50.0,
                    buffer_m,
                };
                let mut tiler =
                    Tiler::new(grid, &layout, &files, dir.path(), 512 << 20, (0.0, 0.0));
                tiler.push_chunk(0, 0, &recs).unwrap();
                tiler.open_tiles()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_tiler);
criterion_main!(benches);
