//! Deterministic synthetic street scene with ground truth (classes, segments, planes).
//!
//! A sensor drives along the x axis (y = 0, height `sensor_height_m`) through a straight street:
//! two-lane road with cross-fall and lane markings, kerbs, a red cycle path, grass with trees and
//! a tiled footpath on the left (+y), a tiled footpath with street lights on the right (−y),
//! building facades with recessed windows and doors on both sides, and parked cars on the right.
//!
//! Determinism: every object lives on a lattice along x and draws its properties from an RNG seeded
//! by `hash(seed, kind, index)`. Points are generated per 1 m x-cell with an RNG seeded by
//! `hash(seed, cell)`; a cell is always generated completely and its points are then filtered on
//! their final (noisy) x. Each slab also generates a few margin cells, so a point belongs to
//! exactly one slab whatever the slab bounds (integer bounds are not even required) and the scene
//! is identical for every slab size and order. Segment ids are unique for `length_m` ≤ 1000 km.

mod params;
pub use params::*;

pub(crate) mod layout;
pub(crate) mod sample;
#[cfg(test)]
mod tests;

use layout::*;
use sample::*;

/// Generate all points whose x lies in `[x0, x1)` (slabs tile the drive; x0 < x1), appending
/// to `out` (which is not cleared).
///
/// Deterministic: the result depends only on `params` and the slab bounds, never on other
/// slabs or call order, so slabs can be generated in parallel and the same scene comes out
/// whatever the slab size (bounds need not be whole metres, though callers normally use integer
/// bounds). Points outside `[0, length_m)` are never produced. Invalid bounds or parameters
/// (non-finite, non-positive length or density) produce nothing.
pub fn generate_slab(params: &SceneParams, x0: f64, x1: f64, out: &mut Vec<SynthPoint>) {
    let p = params;
    let (lo, hi) = (x0.max(0.0), x1.min(p.length_m));
    let ok = [
        p.length_m,
        p.points_per_m2,
        p.sensor_height_m,
        p.noise_m,
        p.colour_noise,
    ]
    .iter()
    .all(|v| v.is_finite())
        && p.points_per_m2 > 0.0
        && p.blocks.is_valid();
    if x0.is_nan() || x1.is_nan() || lo >= hi || !ok {
        return;
    }
    let noise = p.noise_m.abs();
    // Points stay within 0.15 m (trunk/pole radius) + 12.2 σ of their generating cell.
    let m = 1 + (0.2 + 12.5 * noise).ceil() as i64;
    let (k0, k1) = (lo.floor() as i64 - m, hi.ceil() as i64 + m);
    out.reserve(((hi - lo) * p.points_per_m2 * 37.0) as usize);
    let mut world = World {
        seed: p.seed,
        blocks: p.blocks,
        cache: Vec::new(),
    };
    let mut em = Em::new(out, lo, hi, p);
    let mut cell = Cell::default();
    for k in k0..k1 {
        world.fill(k, &mut cell);
        em.rng = Rng(hash(p.seed, R_CELL, k));
        // The sensor rides on the road, which climbs with the grade: without this the density
        // fell along long drives (a 4 km drive had 39 M instead of ~100 M points).
        em.h = p.sensor_height_m + layout::GRADE * (k as f64 + 0.5);
        let (xa, xb) = (k as f64, k as f64 + 1.0);
        ground(&mut em, &cell, p.seed, xa, xb);
        facades(&mut em, &cell, xa, xb);
        trees(&mut em, &cell, xa, xb);
        poles(&mut em, &cell);
        cars(&mut em, &cell, xa, xb);
    }
}

/// All segments of the scene (cheap: enumerates the layout, no points).
///
/// Lists every segment that can have points in `[0, length_m)` (a few may end up empty).
/// Segment id = `kind << 26 | index`; road, kerb, cycle path, grass, footpath and edge-line
/// segments are cut into 60 m blocks, centre-line dashes are 3 m long every 9 m.
pub fn segments(params: &SceneParams) -> Vec<SegmentTruth> {
    let len = params.length_m;
    let mut v = Vec::new();
    if len.is_nan() || len <= 0.0 || len.is_infinite() {
        return v;
    }
    let pad = 0.2 + 12.5 * params.noise_m.abs();
    let mut add = |kind: u32, idx: u64, pl: Option<([f64; 3], f64)>, xa: f64, xb: f64| {
        if xb > -pad && xa < len + pad {
            let (normal, d) = pl.unwrap_or(([0.0; 3], 0.0));
            v.push(SegmentTruth {
                id: sid(kind, idx),
                class: class_of(kind),
                kind: KINDS[(kind - 1) as usize].0,
                planar: pl.is_some(),
                normal,
                d,
                x_min: xa.clamp(0.0, len),
                x_max: xb.clamp(0.0, len),
            });
        }
    };
    for b in 0..(len / ROAD_BLOCK).ceil() as u64 {
        let xa = b as f64 * ROAD_BLOCK;
        for kind in [
            K_ROAD_L, K_ROAD_R, K_EDGE_L, K_EDGE_R, K_KFACE_L, K_KTOP_L, K_KFACE_R, K_KTOP_R,
            K_CYCLE, K_GRASS, K_FOOT_L, K_FOOT_R,
        ] {
            add(kind, b, ground_plane(kind), xa, xa + ROAD_BLOCK);
        }
    }
    for k in 0..((len + pad) / DASH_PITCH).ceil() as u64 {
        let xa = k as f64 * DASH_PITCH;
        add(K_DASH, k, ground_plane(K_DASH), xa, xa + DASH_LEN);
    }
    let mut bs = Vec::new();
    for b in 0..((len + pad) / params.blocks.block_m).ceil() as i64 {
        for left in [true, false] {
            block_buildings(params.seed, left, b, &params.blocks, &mut bs);
        }
    }
    for b in &bs {
        let n = if b.left { -1.0 } else { 1.0 };
        let pl = |what: u8| Some(([0.0, n, 0.0], n * -b.plane_y(what)));
        add(K_FACADE, b.gid, pl(0), b.xa, b.xb);
        add(K_DOOR, b.gid, pl(2), b.dxa, b.dxb);
        for f in 0..b.floors {
            for c in (0..b.cols).filter(|&c| f > 0 || c != b.door) {
                let xw = b.window_x(c);
                add(
                    K_WINDOW,
                    b.gid * 128 + u64::from(f * 16 + c),
                    pl(1),
                    xw,
                    xw + b.ww,
                );
            }
        }
    }
    let s = params.seed;
    for i in 0..=((len + 12.0) / TREE_PITCH) as i64 {
        if let Some(t) = tree(s, i) {
            add(K_TRUNK, t.i, None, t.x - 0.15, t.x + 0.15);
            add(K_CROWN, t.i, None, t.x - t.a, t.x + t.a);
        }
    }
    for i in 0..=((len + 2.0) / POLE_PITCH) as i64 {
        if let Some(p) = pole(s, i) {
            add(K_POLE, p.i, None, p.x - 0.08, p.x + 0.08);
        }
    }
    for i in 0..=((len + 6.0) / CAR_PITCH) as i64 {
        if let Some(c) = car(s, i) {
            add(K_CAR, c.i, None, c.xa, c.xb);
        }
    }
    v
}
