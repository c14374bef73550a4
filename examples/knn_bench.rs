//! Times the neighbour searches on the ground points of a labelled tile.
//! `cargo run --release --example knn_bench POINTS.bin [K] [R]` (little-endian f64 x, y, z)
use std::time::Instant;
use tessera::segment::neighbours::{knn_grid2d, knn_surface, knn_voxel};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let k: usize = a.get(2).map(|s| s.parse().unwrap()).unwrap_or(12);
    let r: f64 = a.get(3).map(|s| s.parse().unwrap()).unwrap_or(0.35);
    let raw = std::fs::read(&a[1]).unwrap();
    let pts: Vec<[f64; 3]> = raw
        .chunks_exact(24)
        .map(|c| {
            std::array::from_fn(|d| f64::from_le_bytes(c[8 * d..8 * d + 8].try_into().unwrap()))
        })
        .collect();
    println!("{} ground points, k {k}, r {r}", pts.len());
    if std::env::var("ONLY_VOXEL").is_ok() {
        for _ in 0..5 {
            let t = Instant::now();
            let b = knn_voxel(&pts, k, r);
            println!(
                "voxel {:.3} s ({} lists)",
                t.elapsed().as_secs_f64(),
                b.len()
            );
        }
        return;
    }
    if std::env::var("ONLY_GRID").is_ok() {
        for _ in 0..5 {
            let t = Instant::now();
            let b = knn_grid2d(&pts, k, r);
            println!(
                "grid2d {:.3} s ({} lists)",
                t.elapsed().as_secs_f64(),
                b.len()
            );
        }
        return;
    }
    for _ in 0..2 {
        let t = Instant::now();
        let a = knn_surface(&pts, k, r);
        let ta = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let b = knn_grid2d(&pts, k, r);
        let tb = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let c = knn_voxel(&pts, k, r);
        let tc = t.elapsed().as_secs_f64();
        let same = (0..pts.len()).filter(|&i| a.of(i) == b.of(i)).count();
        let same_c = (0..pts.len()).filter(|&i| c.of(i) == b.of(i)).count();
        println!("surface (2-D kd-tree) {ta:.3} s, grid2d {tb:.3} s, voxel {tc:.3} s; lists equal surface/grid {same}, voxel/grid {same_c}");
    }
}
