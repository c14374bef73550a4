//! Non-ground classes from geometry: building/facade, high vegetation, pole-like, vehicle,
//! other. Two levels:
//!
//! 1. **Planar segments** (from the segmentation stage) become building when they are a facade
//!    (near-vertical, tall and long) or a roof (raised above the ground, large, smooth, and, when
//!    returns are recorded, mostly single returns: vegetation gives multiple returns).
//! 2. The remaining non-ground points are grouped into **objects** by 3-D connectivity on a
//!    voxel grid; each object is classified from its height above the ground, its horizontal
//!    extents (principal axes) and its eigenvalue shape (linearity, scattering). Objects that
//!    match no rule but touch a building segment (windows, doors, balconies, roof edges) join
//!    the building.
//!
//! Heights are above a ground grid built from the tile's ground points (cell means, holes
//! filled from the nearest filled cells).

use crate::rng::{FastMap, FastSet};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Rule thresholds (all documented in `config/default.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectParams {
    /// Cell of the ground height grid, metres.
    pub ground_cell_m: f64,
    /// Voxel edge for object connectivity, metres.
    pub voxel_m: f64,
    /// Facade segment: |n_z| at most this (near-vertical plane).
    pub facade_max_nz: f64,
    /// Facade segment: at least this tall, metres.
    pub facade_min_height_m: f64,
    /// Facade segment: at least this long horizontally, metres.
    pub facade_min_length_m: f64,
    /// Roof segment: mean height above ground at least this, metres.
    pub roof_min_height_m: f64,
    /// Roof segment: horizontal bounding area at least this, m².
    pub roof_min_area_m2: f64,
    /// Roof segment: RMS distance to its plane at most this, metres.
    pub roof_max_rms_m: f64,
    /// Facade and roof segments: share of points that are not the last return of their pulse
    /// at most this (a solid surface ends the pulse; foliage lets it through). Ignored when
    /// the data have no return numbers.
    pub max_non_last_return: f64,
    /// Segments with fewer points are not judged as planes.
    pub min_segment_points: usize,
    /// Pole: top at least this high above ground, metres.
    pub pole_min_height_m: f64,
    /// Pole: minor horizontal extent at most this, metres.
    pub pole_max_width_m: f64,
    /// Vehicle: top height above ground in this range, metres.
    pub vehicle_height_m: [f64; 2],
    /// Vehicle: major horizontal extent in this range, metres.
    pub vehicle_length_m: [f64; 2],
    /// Vehicle: minor horizontal extent in this range, metres.
    pub vehicle_width_m: [f64; 2],
    /// Vehicle: lowest point at most this far above ground, metres.
    pub vehicle_max_clearance_m: f64,
    /// High vegetation: top at least this high above ground, metres.
    pub vegetation_min_height_m: f64,
    /// Objects with fewer points are `other`.
    pub min_object_points: usize,
}

impl Default for ObjectParams {
    fn default() -> Self {
        ObjectParams {
            ground_cell_m: 1.0,
            voxel_m: 0.5,
            facade_max_nz: 0.3,
            facade_min_height_m: 2.0,
            facade_min_length_m: 2.0,
            roof_min_height_m: 2.5,
            roof_min_area_m2: 10.0,
            roof_max_rms_m: 0.15,
            max_non_last_return: 0.35,
            min_segment_points: 30,
            pole_min_height_m: 2.5,
            pole_max_width_m: 0.8,
            vehicle_height_m: [1.0, 2.8],
            vehicle_length_m: [2.5, 7.5],
            vehicle_width_m: [1.2, 3.0],
            vehicle_max_clearance_m: 0.7,
            vegetation_min_height_m: 2.0,
            min_object_points: 10,
        }
    }
}

/// Non-ground class decided for a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectClass {
    /// Building, facade, roof and what is attached to them.
    Building,
    /// Trees.
    HighVegetation,
    /// Poles, street lights, sign posts.
    Pole,
    /// Cars, vans.
    Vehicle,
    /// Everything else.
    Other,
}

/// Input of [`classify_objects`], all slices over the tile's points.
pub struct ObjectInput<'a> {
    /// Coordinates.
    pub xyz: &'a [[f64; 3]],
    /// Ground points (class 2) anywhere in the tile: the height reference.
    pub is_ground: &'a [bool],
    /// Points to classify.
    pub todo: &'a [bool],
    /// Segment id per point (0: none); planes and RMS are refitted from the points given.
    pub segment: &'a [u32],
    /// Whether a point is an earlier (not the last) return of its pulse (None: not recorded).
    pub non_last_return: Option<&'a [bool]>,
}

/// Height of the ground under any xy: cell means of the ground points, empty cells filled by
/// repeated dilation from their filled neighbours.
pub struct GroundGrid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    z: Vec<f64>,
}

impl GroundGrid {
    /// Builds the grid over the bounding box of `xyz`, its cells aligned to multiples of `cell`.
    pub fn new(xyz: &[[f64; 3]], is_ground: &[bool], cell: f64) -> Self {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in xyz {
            lo = [lo[0].min(p[0]), lo[1].min(p[1])];
            hi = [hi[0].max(p[0]), hi[1].max(p[1])];
        }
        if !lo[0].is_finite() {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        // Cells on the world grid of this cell size, not on the tile's corner: a cell then
        // averages the same ground points whatever the tile layout. A tile of a few points
        // spread over kilometres (sparse inputs get large tiles) takes cells twice, four
        // times, … as wide, so the grid never has many more cells than the tile has points.
        let most = 4 * xyz.len() + 65_536;
        let mut cell = cell;
        let (lo, nx, ny) = loop {
            let lo = lo.map(|v| (v / cell).floor() * cell);
            let n = |d: usize| ((hi[d] - lo[d]) / cell).floor() + 1.0;
            if n(0) * n(1) <= most as f64 || !cell.is_finite() {
                break (
                    lo,
                    (n(0) as usize).clamp(1, 1 << 14),
                    (n(1) as usize).clamp(1, 1 << 14),
                );
            }
            cell *= 2.0;
        };
        let mut sum = vec![0.0; nx * ny];
        let mut cnt = vec![0u32; nx * ny];
        let mut g = GroundGrid {
            x0: lo[0],
            y0: lo[1],
            cell,
            nx,
            ny,
            z: Vec::new(),
        };
        let mut zmin = f64::INFINITY;
        for (p, &gr) in xyz.iter().zip(is_ground) {
            if gr {
                let k = g.index(p[0], p[1]);
                sum[k] += p[2];
                cnt[k] += 1;
                zmin = zmin.min(p[2]);
            }
        }
        if !zmin.is_finite() {
            // No ground in the tile: heights above the lowest point.
            zmin = xyz.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
            g.z = vec![if zmin.is_finite() { zmin } else { 0.0 }; nx * ny];
            return g;
        }
        let mut z: Vec<f64> = sum
            .iter()
            .zip(&cnt)
            .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
            .collect();
        dilate_ground(&mut z, nx, ny);
        for v in &mut z {
            if v.is_nan() {
                *v = zmin;
            }
        }
        g.z = z;
        g
    }

    fn index(&self, x: f64, y: f64) -> usize {
        let ix = (((x - self.x0) / self.cell).floor().max(0.0) as usize).min(self.nx - 1);
        let iy = (((y - self.y0) / self.cell).floor().max(0.0) as usize).min(self.ny - 1);
        iy * self.nx + ix
    }

    /// Height of point `p` above the ground.
    pub fn height(&self, p: &[f64; 3]) -> f64 {
        p[2] - self.z[self.index(p[0], p[1])]
    }
}

/// Fills the empty (NaN) cells of a `nx` × `ny` grid in waves: each wave gives the empty
/// cells next to filled ones the mean of their filled 8-neighbours of earlier waves (the
/// neighbours added in the same order as a pass over the whole grid would). Each cell is
/// visited once per wave that reaches it, not every cell once per wave: a tile with two
/// ground cells kilometres apart used to take a pass over the grid per cell of distance.
fn dilate_ground(z: &mut [f64], nx: usize, ny: usize) {
    const NONE: u32 = u32::MAX;
    let mut wave: Vec<u32> = z
        .iter()
        .map(|v| if v.is_nan() { NONE } else { 0 })
        .collect();
    if !wave.contains(&NONE) {
        return;
    }
    let mut front: Vec<usize> = (0..z.len()).filter(|&k| wave[k] == 0).collect();
    // The 3 × 3 block around cell k within the grid, rows then columns (as a pass reads it).
    let block = |k: usize| {
        let (ix, iy) = (k % nx, k / nx);
        (
            ix.saturating_sub(1)..(ix + 2).min(nx),
            iy.saturating_sub(1)..(iy + 2).min(ny),
        )
    };
    let mut level = 0u32;
    let mut next: Vec<usize> = Vec::new();
    while !front.is_empty() {
        level += 1;
        next.clear();
        for &k in &front {
            let (xs, ys) = block(k);
            for y in ys {
                for x in xs.clone() {
                    let j = y * nx + x;
                    if wave[j] == NONE {
                        wave[j] = level;
                        next.push(j);
                    }
                }
            }
        }
        // Row-major order, as a pass over the grid takes them (the values do not depend on
        // it: each reads only earlier waves).
        next.sort_unstable();
        for &j in &next {
            let (xs, ys) = block(j);
            let (mut s, mut c) = (0.0, 0);
            for y in ys {
                for x in xs.clone() {
                    let i = y * nx + x;
                    if wave[i] < level {
                        s += z[i];
                        c += 1;
                    }
                }
            }
            z[j] = s / c as f64;
        }
        std::mem::swap(&mut front, &mut next);
    }
}

/// Symmetric 3×3 eigenvalues (descending) and the eigenvectors of the largest and the
/// smallest ([`crate::geom::sym3_eigen`]).
fn eigen3(cov: [[f64; 3]; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let (vals, vecs) = crate::geom::sym3_eigen(cov);
    (
        [vals[2], vals[1], vals[0]].map(|v| v.max(0.0)),
        vecs[2],
        vecs[0],
    )
}

/// Shape of a set of points.
#[derive(Debug, Clone, Default)]
struct Shape {
    n: usize,
    hag_min: f64,
    hag_max: f64,
    /// Horizontal extents along the principal axes (major, minor), metres.
    len: [f64; 2],
    /// Eigenvalues of the 3-D covariance (descending).
    eig: [f64; 3],
    /// |z| of the principal axis.
    vert: f64,
    /// z range.
    zext: f64,
    /// Normal of the least-squares plane (smallest eigenvector).
    normal: [f64; 3],
    /// RMS distance to that plane (√ of the smallest eigenvalue).
    rms: f64,
}

fn shape(xyz: &[[f64; 3]], idx: &[u32], hag: &[f64]) -> Shape {
    let n = idx.len();
    if n == 0 {
        return Shape::default();
    }
    let o = xyz[idx[0] as usize];
    let mut m = [0.0; 3];
    let (mut hmin, mut hmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut zmin, mut zmax) = (f64::INFINITY, f64::NEG_INFINITY);
    for &i in idx {
        let p = xyz[i as usize];
        for c in 0..3 {
            m[c] += p[c] - o[c];
        }
        hmin = hmin.min(hag[i as usize]);
        hmax = hmax.max(hag[i as usize]);
        zmin = zmin.min(p[2]);
        zmax = zmax.max(p[2]);
    }
    let m = m.map(|v| v / n as f64);
    let mut cov = [[0.0; 3]; 3];
    for &i in idx {
        let p = xyz[i as usize];
        let d = [p[0] - o[0] - m[0], p[1] - o[1] - m[1], p[2] - o[2] - m[2]];
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += d[r] * d[c];
            }
        }
    }
    let cov = cov.map(|r| r.map(|v| v / n as f64));
    let (eig, v1, v3) = eigen3(cov);
    // Horizontal principal axes from the 2×2 xy covariance, extents as projection ranges.
    let (a, b, c) = (cov[0][0], cov[0][1], cov[1][1]);
    let theta = 0.5 * (2.0 * b).atan2(a - c);
    let (u, w) = ([theta.cos(), theta.sin()], [-theta.sin(), theta.cos()]);
    let (mut ru, mut rw) = (
        [f64::INFINITY, f64::NEG_INFINITY],
        [f64::INFINITY, f64::NEG_INFINITY],
    );
    for &i in idx {
        let p = xyz[i as usize];
        let (dx, dy) = (p[0] - o[0], p[1] - o[1]);
        let pu = dx * u[0] + dy * u[1];
        let pw = dx * w[0] + dy * w[1];
        ru = [ru[0].min(pu), ru[1].max(pu)];
        rw = [rw[0].min(pw), rw[1].max(pw)];
    }
    let (l1, l2) = (ru[1] - ru[0], rw[1] - rw[0]);
    Shape {
        n,
        hag_min: hmin,
        hag_max: hmax,
        len: [l1.max(l2), l1.min(l2)],
        eig,
        vert: v1[2].abs(),
        zext: zmax - zmin,
        normal: v3,
        rms: eig[2].sqrt(),
    }
}

/// Counters for the report.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ObjectStats {
    /// Planar segments judged building.
    pub building_segments: usize,
    /// Objects (connected groups of the other non-ground points).
    pub objects: usize,
    /// Points per class.
    pub points: HashMap<ObjectClass, usize>,
    /// Object of each tile point (1..=objects; 0: building segment, ground or not
    /// classified), for the classifier's object features.
    #[serde(skip)]
    pub object: Vec<u32>,
}

/// Classifies the points with `todo` set. Returns a class per tile point (`None` where
/// `todo` is false) and counters.
pub fn classify_objects(
    inp: &ObjectInput<'_>,
    p: &ObjectParams,
) -> (Vec<Option<ObjectClass>>, ObjectStats) {
    let n = inp.xyz.len();
    let grid = GroundGrid::new(inp.xyz, inp.is_ground, p.ground_cell_m);
    let hag: Vec<f64> = inp
        .xyz
        .iter()
        .zip(inp.todo)
        .map(|(q, &t)| if t { grid.height(q) } else { 0.0 })
        .collect();
    let mut out: Vec<Option<ObjectClass>> = vec![None; n];
    let mut stats = ObjectStats::default();

    // 1. Planar segments.
    let n_seg = inp.segment.iter().copied().max().unwrap_or(0) as usize;
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); n_seg];
    for i in 0..n {
        let s = inp.segment[i];
        if inp.todo[i] && s != 0 && (s as usize) <= members.len() {
            members[s as usize - 1].push(i as u32);
        }
    }
    for idx in &members {
        if idx.len() < p.min_segment_points {
            continue;
        }
        let sh = shape(inp.xyz, idx, &hag);
        let (normal, rms) = (sh.normal, sh.rms);
        let non_last = inp.non_last_return.map_or(0.0, |m| {
            idx.iter().filter(|&&i| m[i as usize]).count() as f64 / idx.len() as f64
        });
        let solid = non_last <= p.max_non_last_return;
        let facade = normal[2].abs() <= p.facade_max_nz
            && sh.zext >= p.facade_min_height_m
            && sh.len[0] >= p.facade_min_length_m
            && solid;
        let mean_hag = idx.iter().map(|&i| hag[i as usize]).sum::<f64>() / idx.len() as f64;
        let roof = normal[2].abs() > p.facade_max_nz
            && mean_hag >= p.roof_min_height_m
            && sh.len[0] * sh.len[1] >= p.roof_min_area_m2
            && rms <= p.roof_max_rms_m
            && solid;
        if facade || roof {
            stats.building_segments += 1;
            for &i in idx {
                out[i as usize] = Some(ObjectClass::Building);
            }
        }
    }

    // 2. Objects: voxel connectivity of the remaining points; voxels holding building points
    // are remembered so that unmatched objects touching them join the building.
    let key = |q: &[f64; 3]| {
        (
            (q[0] / p.voxel_m).floor() as i64,
            (q[1] / p.voxel_m).floor() as i64,
            (q[2] / p.voxel_m).floor() as i64,
        )
    };
    let mut building_vox: FastSet<(i64, i64, i64)> = Default::default();
    let mut vox: FastMap<(i64, i64, i64), u32> = FastMap::default();
    let mut vox_keys: Vec<(i64, i64, i64)> = Vec::new();
    let mut point_vox = vec![u32::MAX; n];
    for i in 0..n {
        if !inp.todo[i] {
            continue;
        }
        let k = key(&inp.xyz[i]);
        if out[i] == Some(ObjectClass::Building) {
            building_vox.insert(k);
            continue;
        }
        let next = vox_keys.len() as u32;
        let v = *vox.entry(k).or_insert_with(|| {
            vox_keys.push(k);
            next
        });
        point_vox[i] = v;
    }
    let mut parent: Vec<u32> = (0..vox_keys.len() as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            let q = parent[x as usize];
            parent[x as usize] = parent[q as usize];
            x = q;
        }
        x
    }
    for (v, k) in vox_keys.iter().enumerate() {
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(&w) = vox.get(&(k.0 + dx, k.1 + dy, k.2 + dz)) {
                        let (a, b) = (find(&mut parent, v as u32), find(&mut parent, w));
                        if a != b {
                            // Smaller root wins: deterministic.
                            let (lo, hi) = (a.min(b), a.max(b));
                            parent[hi as usize] = lo;
                        }
                    }
                }
            }
        }
    }
    let mut objects: FastMap<u32, Vec<u32>> = FastMap::default();
    for (i, &v) in point_vox.iter().enumerate() {
        if v != u32::MAX {
            let r = find(&mut parent, v);
            objects.entry(r).or_default().push(i as u32);
        }
    }
    let mut touching: FastMap<u32, bool> = FastMap::default();
    for (v, k) in vox_keys.iter().enumerate() {
        let t = (-1..=1).any(|dz| {
            (-1..=1)
                .any(|dy| (-1..=1).any(|dx| building_vox.contains(&(k.0 + dx, k.1 + dy, k.2 + dz))))
        });
        if t {
            touching.insert(find(&mut parent, v as u32), true);
        }
    }
    stats.objects = objects.len();
    stats.object = vec![0; n];
    let mut roots: Vec<u32> = objects.keys().copied().collect();
    roots.sort_unstable();
    for (k, root) in roots.iter().enumerate() {
        let idx = &objects[root];
        let sh = shape(inp.xyz, idx, &hag);
        let c = classify_shape(&sh, p, touching.contains_key(root));
        for &i in idx {
            out[i as usize] = Some(c);
            stats.object[i as usize] = k as u32 + 1;
        }
    }
    for c in out.iter().flatten() {
        *stats.points.entry(*c).or_default() += 1;
    }
    (out, stats)
}

fn classify_shape(sh: &Shape, p: &ObjectParams, touches_building: bool) -> ObjectClass {
    if sh.n < p.min_object_points {
        return if touches_building {
            ObjectClass::Building
        } else {
            ObjectClass::Other
        };
    }
    let l0 = sh.eig[0].max(1e-12);
    let scattering = sh.eig[2] / l0;
    let [len, width] = sh.len;
    // Pieces attached to a facade or roof (window reveals, balconies, downpipes) are building
    // unless they look like foliage: tested before the pole rule, which thin vertical reveals
    // would otherwise satisfy.
    if touches_building && scattering < 0.05 {
        return ObjectClass::Building;
    }
    // Pole: tall and thin; an arm makes the major extent longer but the height dominates.
    if sh.hag_max >= p.pole_min_height_m
        && width <= p.pole_max_width_m
        && (sh.vert >= 0.8 || sh.zext >= 2.0 * len)
    {
        return ObjectClass::Pole;
    }
    let within = |v: f64, r: [f64; 2]| v >= r[0] && v <= r[1];
    if sh.hag_min <= p.vehicle_max_clearance_m
        && within(sh.hag_max, p.vehicle_height_m)
        && within(len, p.vehicle_length_m)
        && within(width, p.vehicle_width_m)
    {
        return ObjectClass::Vehicle;
    }
    if sh.hag_max >= p.vegetation_min_height_m {
        return ObjectClass::HighVegetation;
    }
    if touches_building {
        return ObjectClass::Building;
    }
    ObjectClass::Other
}

#[cfg(test)]
mod tests {

    /// The pass-over-the-grid dilation `dilate_ground` replaced, as it was.
    fn dilate_by_passes(z: &mut [f64], nx: usize, ny: usize) {
        loop {
            let mut changed = false;
            let prev = z.to_vec();
            for iy in 0..ny {
                for ix in 0..nx {
                    if !prev[iy * nx + ix].is_nan() {
                        continue;
                    }
                    let (mut s, mut c) = (0.0, 0);
                    for dy in -1i64..=1 {
                        for dx in -1i64..=1 {
                            let (x, y) = (ix as i64 + dx, iy as i64 + dy);
                            if x < 0 || y < 0 || x >= nx as i64 || y >= ny as i64 {
                                continue;
                            }
                            let v = prev[y as usize * nx + x as usize];
                            if !v.is_nan() {
                                s += v;
                                c += 1;
                            }
                        }
                    }
                    if c > 0 {
                        z[iy * nx + ix] = s / c as f64;
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
    }

    #[test]
    fn ground_dilation_in_waves_equals_passes_bit_for_bit() {
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for (nx, ny, fill) in [
            (1, 1, 1.0),
            (7, 5, 0.1),
            (40, 33, 0.02),
            (64, 64, 0.3),
            (9, 1, 0.0),
        ] {
            let z: Vec<f64> = (0..nx * ny)
                .map(|_| {
                    if next() < fill {
                        100.0 * next()
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let (mut a, mut b) = (z.clone(), z);
            super::dilate_ground(&mut a, nx, ny);
            dilate_by_passes(&mut b, nx, ny);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "{nx} x {ny}, fill {fill}");
        }
    }

    #[test]
    fn ground_grid_of_far_flung_points_stays_small() {
        // Two ground points 40 km apart and one point above: cells coarsen, heights hold.
        let xyz = [
            [0.0, 0.0, 10.0],
            [40_000.0, 30_000.0, 10.0],
            [20_000.0, 15_000.0, 15.0],
        ];
        let g = super::GroundGrid::new(&xyz, &[true, true, false], 1.0);
        assert!(g.nx * g.ny <= 4 * 3 + 65_536, "{} x {}", g.nx, g.ny);
        assert!((g.height(&xyz[2]) - 5.0).abs() < 1e-9);
    }
    use super::*;

    fn add_box(pts: &mut Vec<[f64; 3]>, lo: [f64; 3], hi: [f64; 3], step: f64) {
        let n = |a: f64, b: f64| ((b - a) / step).round().max(1.0) as usize;
        for i in 0..=n(lo[0], hi[0]) {
            for j in 0..=n(lo[1], hi[1]) {
                for k in 0..=n(lo[2], hi[2]) {
                    let p = [
                        lo[0] + i as f64 * step,
                        lo[1] + j as f64 * step,
                        lo[2] + k as f64 * step,
                    ];
                    // Surface only.
                    let on = |v: f64, a: f64, b: f64| (v - a).abs() < 1e-9 || (v - b).abs() < 1e-9;
                    if on(p[0], lo[0], hi[0]) || on(p[1], lo[1], hi[1]) || on(p[2], lo[2], hi[2]) {
                        pts.push(p);
                    }
                }
            }
        }
    }

    #[test]
    fn pole_vehicle_facade_and_tree() {
        let mut pts = Vec::new();
        // Ground 40 × 20 m.
        for i in 0..200 {
            for j in 0..100 {
                pts.push([i as f64 * 0.2, j as f64 * 0.2, 0.0]);
            }
        }
        let n_ground = pts.len();
        let pole0 = pts.len();
        add_box(&mut pts, [5.0, 5.0, 0.1], [5.2, 5.2, 8.0], 0.05);
        let car0 = pts.len();
        add_box(&mut pts, [10.0, 5.0, 0.3], [14.5, 6.8, 1.5], 0.1);
        let wall0 = pts.len();
        for i in 0..200 {
            for k in 0..100 {
                pts.push([20.0 + i as f64 * 0.05, 15.0, 0.1 + k as f64 * 0.08]);
            }
        }
        let tree0 = pts.len();
        let mut h = 7u64;
        let mut rnd = || {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            (h >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..3000 {
            // Crown: a ball of radius 2 at 5 m, trunk below.
            let (u, v, w) = (rnd() * 2.0 - 1.0, rnd() * 2.0 - 1.0, rnd() * 2.0 - 1.0);
            if u * u + v * v + w * w <= 1.0 {
                pts.push([30.0 + 2.0 * u, 5.0 + 2.0 * v, 5.0 + 2.0 * w]);
            }
        }
        for k in 0..60 {
            pts.push([30.0, 5.0, 0.1 + k as f64 * 0.05]);
        }
        let n = pts.len();
        let is_ground: Vec<bool> = (0..n).map(|i| i < n_ground).collect();
        let todo: Vec<bool> = is_ground.iter().map(|g| !g).collect();
        // The wall is one planar segment; nothing else is segmented.
        let segment: Vec<u32> = (0..n)
            .map(|i| u32::from((wall0..tree0).contains(&i)))
            .collect();
        let (out, stats) = classify_objects(
            &ObjectInput {
                xyz: &pts,
                is_ground: &is_ground,
                todo: &todo,
                segment: &segment,
                non_last_return: None,
            },
            &ObjectParams::default(),
        );
        assert_eq!(stats.building_segments, 1);
        let share = |r: std::ops::Range<usize>, c: ObjectClass| {
            r.clone().filter(|&i| out[i] == Some(c)).count() as f64 / r.len() as f64
        };
        assert!(share(pole0..car0, ObjectClass::Pole) > 0.99);
        assert!(share(car0..wall0, ObjectClass::Vehicle) > 0.99);
        assert!(share(wall0..tree0, ObjectClass::Building) > 0.99);
        assert!(share(tree0..n, ObjectClass::HighVegetation) > 0.99);
        assert!(out[..n_ground].iter().all(|c| c.is_none()));
    }
}
