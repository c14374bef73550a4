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

/// Ground-truth class codes written by the generator (ASPRS LAS 1.4 where they exist, user
/// codes ≥ 64 otherwise).
pub mod truth {
    /// High vegetation (ASPRS 5): tree crowns and tree trunks.
    pub const HIGH_VEGETATION: u8 = 5;
    /// Building (ASPRS 6): facades, windows and doors (told apart only by segment).
    pub const BUILDING: u8 = 6;
    /// Road surface (ASPRS 11): asphalt of the carriageway.
    pub const ROAD: u8 = 11;
    /// Cycle path (red asphalt).
    pub const CYCLE_PATH: u8 = 64;
    /// Tiled footpath.
    pub const FOOTPATH: u8 = 65;
    /// Kerb: vertical face and top strip.
    pub const KERB: u8 = 66;
    /// Grass / terrain.
    pub const GRASS: u8 = 67;
    /// Pole-like objects (street lights, including their arm).
    pub const POLE: u8 = 69;
    /// Vehicles (parked cars).
    pub const VEHICLE: u8 = 70;
    /// Painted lane markings (road surface, but a separate colour segment).
    pub const LANE_MARKING: u8 = 71;
}

/// Parameters of a synthetic scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Length of the drive along x in metres (points have x in `[0, length_m)`).
    pub length_m: f64,
    /// Point density (points/m²) on a surface at 5 m from the drive line.
    pub points_per_m2: f64,
    /// Height of the sensor above the road (m).
    pub sensor_height_m: f64,
    /// Standard deviation of the isotropic Gaussian position noise (m).
    pub noise_m: f64,
    /// Standard deviation of the per-channel colour noise in 8-bit units.
    pub colour_noise: f64,
    /// Building blocks along the street.
    pub blocks: Blocks,
}

/// Building blocks: each side of the street is cut into blocks of `block_m`, filled with
/// buildings whose lengths are drawn from `min_building_m..max_building_m` (each with its own
/// colour). Long blocks of long buildings give terraces whose facades span several tiles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blocks {
    /// Block length along x (m).
    pub block_m: f64,
    /// Shortest building (m); a block ends when less than this is left.
    pub min_building_m: f64,
    /// Longest building (m).
    pub max_building_m: f64,
}

impl Blocks {
    /// 1 ≤ min ≤ max, min ≤ block, all finite.
    pub fn is_valid(&self) -> bool {
        self.min_building_m >= 1.0
            && self.max_building_m >= self.min_building_m
            && self.block_m >= self.min_building_m
            && self.block_m.is_finite()
            && self.max_building_m.is_finite()
    }
}

impl Default for Blocks {
    /// 40 m blocks of 8–25 m buildings.
    fn default() -> Self {
        Blocks {
            block_m: 40.0,
            min_building_m: 8.0,
            max_building_m: 25.0,
        }
    }
}

impl Default for SceneParams {
    /// Seed 42, 100 m, 600 points/m² at 5 m (≈ 2.4 million points per 100 m), sensor at 2.5 m,
    /// 5 mm noise, colour noise σ = 4 (8-bit units).
    fn default() -> Self {
        SceneParams {
            seed: 42,
            length_m: 100.0,
            points_per_m2: 600.0,
            sensor_height_m: 2.5,
            noise_m: 0.005,
            colour_noise: 4.0,
            blocks: Blocks::default(),
        }
    }
}

/// One generated point. Coordinates are local metres: x along the drive (0..length_m), y across
/// (left positive), z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SynthPoint {
    /// Along the drive (m).
    pub x: f64,
    /// Across the drive, left positive (m).
    pub y: f64,
    /// Up (m).
    pub z: f64,
    /// 16-bit colour: an 8-bit value times 257.
    pub rgb: [u16; 3],
    /// Return intensity (material dependent).
    pub intensity: u16,
    /// Time (s): x / 10 m/s plus a sub-millisecond jitter.
    pub gps_time: f64,
    /// Ground-truth class, see [`truth`].
    pub class: u8,
    /// Ground-truth segment id, see [`segments`].
    pub segment: u32,
}

/// Truth for one segment (ids are unique over the whole scene, > 0).
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentTruth {
    /// Segment id as written in [`SynthPoint::segment`].
    pub id: u32,
    /// Class of all points of the segment.
    pub class: u8,
    /// Kind of surface: "road_left", "facade", "window", "crown", "vehicle", ...
    pub kind: &'static str,
    /// Whether the segment is a plane (then `normal`/`d` are meaningful).
    pub planar: bool,
    /// Unit normal of the plane `normal · p + d = 0` (zero when not planar).
    pub normal: [f64; 3],
    /// Offset of the plane `normal · p + d = 0`.
    pub d: f64,
    /// Smallest nominal x of the segment, clipped to the scene.
    pub x_min: f64,
    /// Largest nominal x of the segment, clipped to the scene.
    pub x_max: f64,
}

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
