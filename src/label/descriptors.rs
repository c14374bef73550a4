//! Per-point descriptors for the labelling classifier ([`super::forest`]).
//!
//! Real sensors give very uneven densities: a 64-beam scanner puts thousands of points per m²
//! next to the car and a few dozen at 30 m; an airborne tile has 4–10 per m². A fixed-radius
//! neighbourhood of raw points is either empty far away or enormous close by. Here each scale
//! is a voxel grid (edges 0.1, 0.2, … 3.2 m) whose occupied voxels are reduced to their
//! centroids, and a point's neighbourhood at a scale is the centroids of the 3 × 3 × 3 block
//! of voxels around its own (the multi-scale pyramid of Hackel, Wegner & Schindler 2016,
//! with a fixed block instead of k nearest centroids). The cost per voxel and scale is
//! bounded (27 look-ups) whatever the density, and the shape measured at a scale is that of
//! the surface, not of the sampling pattern.
//!
//! A point reads each scale's block statistics interpolated trilinearly between the 8 voxels
//! whose centres surround it, not those of its own voxel alone: with one voxel, a point's
//! features jumped where a voxel edge fell, and a trained model's scores moved with the
//! grid's placement (SemanticKITTI vehicle F1 0.23–0.71 over seven placements). The grids
//! are anchored to the world (a 4,096 m grid), so a tile's layout does not move them.
//!
//! Per scale: the block's occupancy, the share of its points from multi-return pulses (foliage
//! lets part of a pulse through, roofs do not), the eigenvalue shape of the centroids (linearity,
//! planarity, scattering; Demantké et al. 2011), the verticality of the normal and of the
//! principal axis, and where the point sits in the block's height range. Besides: height
//! above the ground grid, the point's vertical column at two cell sizes, the shape of its
//! segment (region growing), the rule classes ([`super::objects`], [`super::kerbs`]) as
//! indicator features, and return and intensity features when the data have them (−1 when
//! not: the forest learns that "missing" is a value).
//!
//! Everything is computed per voxel of the finest scale where possible, then read per point,
//! so the memory per point is a few words per scale.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Voxel edges of the scales, metres.
pub const SCALES: [f64; 6] = [0.1, 0.2, 0.4, 0.8, 1.6, 3.2];
/// Column cell sizes, metres.
pub const COLUMNS: [f64; 2] = [0.5, 2.0];
/// Rule classes given as indicator features, in this order.
pub const RULES: [&str; 9] = [
    "none",
    "building",
    "vegetation",
    "pole",
    "vehicle",
    "other",
    "road",
    "sidewalk",
    "terrain",
];

const PER_SCALE: [&str; 10] = [
    "occupancy",
    "linearity",
    "planarity",
    "scattering",
    "normal_z",
    "axis_z",
    "z_rel_mean",
    "z_below_max",
    "z_above_min",
    "multi_return_share",
];

/// Names of the features, in the order [`Descriptors::row`] writes them. A model records
/// them and is refused when they differ (a model trained by another version).
pub fn feature_names() -> Vec<String> {
    let mut v = Vec::new();
    for s in SCALES {
        for n in PER_SCALE {
            v.push(format!("s{s}_{n}"));
        }
    }
    for c in COLUMNS {
        for n in ["z_below_max", "z_above_min", "range"] {
            v.push(format!("col{c}_{n}"));
        }
    }
    for n in [
        "height_above_ground",
        "is_ground",
        "seg_log_points",
        "seg_normal_z",
        "seg_z_extent",
        "seg_major",
        "seg_minor",
        "seg_height_above_ground",
        "seg_top_above_ground",
        "obj_log_points",
        "obj_normal_z",
        "obj_z_extent",
        "obj_major",
        "obj_minor",
        "obj_height_above_ground",
        "obj_top_above_ground",
        "above_ground_min_2m",
        "above_ground_min_5m",
        "above_ground_max_2m",
        "non_last_return",
        "returns",
        "intensity",
    ] {
        v.push(n.to_string());
    }
    for r in RULES {
        v.push(format!("rule_{r}"));
    }
    v
}

/// Number of features.
pub fn feature_count() -> usize {
    SCALES.len() * PER_SCALE.len() + COLUMNS.len() * 3 + 2 + 2 * SHAPE + 3 + 3 + RULES.len()
}

/// Multiply–shift hashing of packed voxel keys (std's SipHash is several times slower here
/// and needs no protection against adversarial keys).
#[derive(Default)]
struct KeyHasher(u64);
impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, _: &[u8]) {
        unreachable!("only u64 keys are hashed")
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (v ^ (v >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    }
}
type KeyMap = HashMap<u64, u32, BuildHasherDefault<KeyHasher>>;

const BIAS: i64 = 1 << 20;
fn pack(ix: i64, iy: i64, iz: i64) -> u64 {
    (((ix + BIAS) as u64) << 42) | (((iy + BIAS) as u64) << 21) | ((iz + BIAS) as u64)
}

/// Inputs, slices over the same points (the tile's points, or a subset with context).
pub struct DescribeInput<'a> {
    /// Coordinates.
    pub xyz: &'a [[f64; 3]],
    /// Height above the ground grid.
    pub hag: &'a [f64],
    /// Ground filter's decision.
    pub is_ground: &'a [bool],
    /// Segment id (0: none).
    pub segment: &'a [u32],
    /// Object id of the rules' voxel connectivity (0: none).
    pub object: &'a [u32],
    /// Rule class per point, an index into [`RULES`].
    pub rule: &'a [u8],
    /// Whether a point is an earlier (not last) return; None when not recorded.
    pub non_last: Option<&'a [bool]>,
    /// Number of returns of the pulse; None when not recorded.
    pub returns: Option<&'a [u8]>,
    /// Intensity scaled to 0..1 (by the tile's 99th percentile); None when not recorded.
    pub intensity: Option<&'a [f32]>,
}

/// Sums over the points of a voxel.
#[derive(Clone, Copy)]
struct Acc {
    sum: [f64; 3],
    n: u32,
    multi: u32,
    zmin: f32,
    zmax: f32,
}

impl Acc {
    fn of_point(p: &[f64; 3], multi: bool) -> Acc {
        Acc {
            sum: *p,
            n: 1,
            multi: u32::from(multi),
            zmin: p[2] as f32,
            zmax: p[2] as f32,
        }
    }
    fn merge(&mut self, o: &Acc) {
        for (s, v) in self.sum.iter_mut().zip(&o.sum) {
            *s += v;
        }
        self.n += o.n;
        self.multi += o.multi;
        self.zmin = self.zmin.min(o.zmin);
        self.zmax = self.zmax.max(o.zmax);
    }
    fn centroid(&self) -> [f64; 3] {
        self.sum.map(|s| s / self.n as f64)
    }
}

/// The occupied voxels of one scale.
#[derive(Default)]
struct Voxels {
    map: KeyMap,
    keys: Vec<[i64; 3]>,
    acc: Vec<Acc>,
}

impl Voxels {
    /// Adds `a` to voxel `k`; returns the voxel's index.
    fn add(&mut self, k: [i64; 3], a: &Acc) -> u32 {
        let next = self.acc.len() as u32;
        let id = *self.map.entry(pack(k[0], k[1], k[2])).or_insert(next);
        if id == next {
            self.keys.push(k);
            self.acc.push(*a);
        } else {
            self.acc[id as usize].merge(a);
        }
        id
    }

    /// Per voxel (the `wanted` ones; the others stay −1): the statistics of the centroids of
    /// its 3 × 3 × 3 block, see [`Scale::stats`].
    fn block_stats(&self, wanted: &[bool], returns: bool) -> Vec<[f32; 10]> {
        let centroid: Vec<[f64; 3]> = self.acc.iter().map(Acc::centroid).collect();
        let mut stats = vec![[-1.0f32; 10]; self.acc.len()];
        let mut block: Vec<u32> = Vec::with_capacity(27);
        for (v, k) in self.keys.iter().enumerate() {
            if !wanted[v] {
                continue;
            }
            block.clear();
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        if let Some(&w) = self.map.get(&pack(k[0] + dx, k[1] + dy, k[2] + dz)) {
                            block.push(w);
                        }
                    }
                }
            }
            let n = block.len() as f64;
            let mut m = [0.0; 3];
            let (mut zmin, mut zmax) = (f32::INFINITY, f32::NEG_INFINITY);
            let (mut points, mut multis) = (0u32, 0u32);
            for &w in &block {
                let a = &self.acc[w as usize];
                points += a.n;
                multis += a.multi;
                let c = centroid[w as usize];
                for (mm, cc) in m.iter_mut().zip(c) {
                    *mm += cc / n;
                }
                zmin = zmin.min(a.zmin);
                zmax = zmax.max(a.zmax);
            }
            let shape = if block.len() >= 3 {
                let mut cov = [[0.0; 3]; 3];
                for &w in &block {
                    let c = centroid[w as usize];
                    let d = [c[0] - m[0], c[1] - m[1], c[2] - m[2]];
                    for r in 0..3 {
                        for s in 0..3 {
                            cov[r][s] += d[r] * d[s] / n;
                        }
                    }
                }
                eigen_shape(cov)
            } else {
                [-1.0; 5]
            };
            stats[v] = [
                block.len() as f32 / 27.0,
                shape[0],
                shape[1],
                shape[2],
                shape[3],
                shape[4],
                m[2] as f32,
                zmin,
                zmax,
                if returns {
                    multis as f32 / points.max(1) as f32
                } else {
                    -1.0
                },
            ];
        }
        stats
    }
}

/// Per-voxel block statistics of one scale, read trilinearly at a point.
struct Scale {
    edge: f64,
    /// Per finest voxel (scales above the finest) or per point (the finest scale): its dual
    /// cell, an index into `corners` (`NONE` where no row is read).
    dual: Vec<u32>,
    /// Per dual cell: the voxels at its 8 corners (`NONE`: unoccupied), corner `dx + 2 dy +
    /// 4 dz` at voxel `base + (dx, dy, dz)`.
    corners: Vec<[u32; 8]>,
    /// Per voxel: occupancy, linearity, planarity, scattering, |n_z|, |axis_z|, mean z,
    /// min z, max z (z relative to the origin), share of points from multi-return pulses.
    stats: Vec<[f32; 10]>,
}

const NONE: u32 = u32::MAX;

/// Values of a group shape.
const SHAPE: usize = 7;
/// Shape of a segment or object: log points, |n_z|, z extent, major and minor horizontal
/// spread (standard deviations), mean and top height above ground.
type SegShape = [f32; SHAPE];

/// Edge of the world grid the descriptors' grids are anchored to, metres.
const ANCHOR: f64 = 4096.0;

/// Cell of the ground-level grid, metres.
const GROUND_CELL: f64 = 0.5;

/// The descriptors of a set of points, computed once and read per point.
pub struct Descriptors<'a> {
    inp: &'a DescribeInput<'a>,
    origin: [f64; 3],
    /// Finest voxel of each point.
    fine: Vec<u32>,
    scales: Vec<Scale>,
    /// Per column size: cell of each point, and per cell (min z, max z).
    columns: Vec<(Vec<u32>, Vec<[f32; 2]>)>,
    segments: HashMap<u32, SegShape>,
    objects: HashMap<u32, SegShape>,
    /// Ground-level grid: cell of each point, and per cell the lowest ground within 2 m and
    /// 5 m and the highest within 2 m (NaN: no ground point there).
    ground_cell: Vec<u32>,
    ground_level: Vec<[f32; 3]>,
}

fn eigen_shape(cov: [[f64; 3]; 3]) -> [f32; 5] {
    let (vals, vecs) = crate::geom::sym3_eigen(cov);
    let l = [vals[2], vals[1], vals[0]].map(|v| v.max(0.0));
    if l[0] <= 1e-12 {
        return [0.0, 0.0, 0.0, -1.0, -1.0];
    }
    [
        ((l[0] - l[1]) / l[0]) as f32,
        ((l[1] - l[2]) / l[0]) as f32,
        (l[2] / l[0]) as f32,
        vecs[0][2].abs() as f32,
        vecs[2][2].abs() as f32,
    ]
}

impl<'a> Descriptors<'a> {
    /// Precomputes the statistics; `which` marks the points whose rows will be read (their
    /// voxels get block statistics), all points serve as context.
    pub fn new(inp: &'a DescribeInput<'a>, which: &[bool]) -> Self {
        // The grids are anchored to the world, not to the tile: x and y at a corner of a
        // 4,096 m grid (a multiple of every cell edge here), z from 0. Anchored to a tile's
        // first point, a model's labels changed with the tile layout (265 of a 30 m street's
        // 610,172 points between 25 m and 50 m tiles).
        let origin = inp.xyz.first().map_or([0.0; 3], |p| {
            [
                (p[0] / ANCHOR).floor() * ANCHOR,
                (p[1] / ANCHOR).floor() * ANCHOR,
                0.0,
            ]
        });
        let local: Vec<[f64; 3]> = inp
            .xyz
            .iter()
            .map(|p| [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]])
            .collect();
        let (fine, scales) = Self::scales(&local, which, inp.returns);
        let columns = COLUMNS
            .iter()
            .map(|&c| {
                let mut map = KeyMap::default();
                let mut cells: Vec<[f32; 2]> = Vec::new();
                let cell: Vec<u32> = local
                    .iter()
                    .map(|p| {
                        let k = pack((p[0] / c).floor() as i64, (p[1] / c).floor() as i64, 0);
                        let next = cells.len() as u32;
                        let id = *map.entry(k).or_insert_with(|| {
                            cells.push([f32::INFINITY, f32::NEG_INFINITY]);
                            next
                        });
                        let z = p[2] as f32;
                        let e = &mut cells[id as usize];
                        *e = [e[0].min(z), e[1].max(z)];
                        id
                    })
                    .collect();
                (cell, cells)
            })
            .collect();
        let segments = group_shapes(inp.segment, inp.hag, &local);
        let objects = group_shapes(inp.object, inp.hag, &local);
        let (ground_cell, ground_level) = ground_levels(&local, inp.is_ground);
        Descriptors {
            inp,
            origin,
            fine,
            scales,
            columns,
            segments,
            objects,
            ground_cell,
            ground_level,
        }
    }

    /// The scales, finest first: the finest voxels from the points, each coarser scale from
    /// the one below (a voxel of edge 2e is the union of 2 × 2 × 2 voxels of edge e, so its
    /// sums are theirs: the points are hashed once, not once per scale). Returns the finest
    /// voxel of each point and the scales.
    ///
    /// A row reads each scale's statistics interpolated between the 8 voxels whose centres
    /// surround the point (its dual cell). Those 8 are found here, once per dual cell, not
    /// once per point: above the finest scale a dual cell is a union of finest voxels (its
    /// faces lie on finest-voxel faces), so it is found once per finest voxel; at the finest
    /// scale once per point.
    fn scales(
        local: &[[f64; 3]],
        which: &[bool],
        returns: Option<&[u8]>,
    ) -> (Vec<u32>, Vec<Scale>) {
        let mut vox = Voxels::default();
        let fine: Vec<u32> = local
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let k = fine_q(p).map(|q| q.floor() as i64);
                let multi = returns.is_some_and(|r| r[i] > 1);
                vox.add(k, &Acc::of_point(p, multi))
            })
            .collect();
        let fine_keys = vox.keys.clone();
        let mut fine_wanted = vec![false; fine_keys.len()];
        for (i, &w) in which.iter().enumerate() {
            if w {
                fine_wanted[fine[i] as usize] = true;
            }
        }
        let mut out = Vec::with_capacity(SCALES.len());
        for (s, &edge) in SCALES.iter().enumerate() {
            let mut duals = KeyMap::default();
            let mut corners: Vec<[u32; 8]> = Vec::new();
            let mut dual_of = |b: [i64; 3]| -> u32 {
                let next = corners.len() as u32;
                *duals.entry(pack(b[0], b[1], b[2])).or_insert_with(|| {
                    corners.push(std::array::from_fn(|c| {
                        let d = [c & 1, (c >> 1) & 1, c >> 2].map(|v| v as i64);
                        vox.map
                            .get(&pack(b[0] + d[0], b[1] + d[1], b[2] + d[2]))
                            .copied()
                            .unwrap_or(NONE)
                    }));
                    next
                })
            };
            let dual: Vec<u32> = if s == 0 {
                local
                    .iter()
                    .zip(which)
                    .map(|(p, &w)| {
                        if w {
                            dual_of(dual_cell(&fine_q(p), s).0)
                        } else {
                            NONE
                        }
                    })
                    .collect()
            } else {
                fine_keys
                    .iter()
                    .zip(&fine_wanted)
                    .map(|(k, &w)| if w { dual_of(coarse_base(k, s)) } else { NONE })
                    .collect()
            };
            let mut wanted = vec![false; vox.acc.len()];
            for c in corners.iter().flatten() {
                if *c != NONE {
                    wanted[*c as usize] = true;
                }
            }
            let stats = vox.block_stats(&wanted, returns.is_some());
            out.push(Scale {
                edge,
                dual,
                corners,
                stats,
            });
            if s + 1 < SCALES.len() {
                let mut up = Voxels::default();
                for (k, a) in vox.keys.iter().zip(&vox.acc) {
                    up.add(k.map(|v| v.div_euclid(2)), a);
                }
                vox = up;
            }
        }
        (fine, out)
    }

    /// Writes the features of point `i` into `out` ([`feature_count`] values).
    pub fn row(&self, i: usize, out: &mut [f32]) {
        let inp = self.inp;
        let z = (inp.xyz[i][2] - self.origin[2]) as f32;
        let mut k = 0;
        let mut put = |v: f32| {
            out[k] = v;
            k += 1;
        };
        let q = fine_q(&[0, 1, 2].map(|c| inp.xyz[i][c] - self.origin[c]));
        for (s, sc) in self.scales.iter().enumerate() {
            let d = if s == 0 {
                sc.dual[i]
            } else {
                sc.dual[self.fine[i] as usize]
            };
            let st = interpolate(sc, &sc.corners[d as usize], dual_cell(&q, s).1);
            for &v in &st[..6] {
                put(v);
            }
            put((z - st[6]) / sc.edge as f32);
            put(st[8] - z);
            put(z - st[7]);
            put(st[9]);
        }
        for (cell, cells) in &self.columns {
            let [lo, hi] = cells[cell[i] as usize];
            put(hi - z);
            put(z - lo);
            put(hi - lo);
        }
        put(inp.hag[i] as f32);
        put(if inp.is_ground[i] { 1.0 } else { 0.0 });
        for (groups, id) in [
            (&self.segments, inp.segment[i]),
            (&self.objects, inp.object[i]),
        ] {
            match groups.get(&id) {
                Some(sh) => sh.iter().for_each(|&v| put(v)),
                None => (0..SHAPE).for_each(|_| put(-1.0)),
            }
        }
        let g = self.ground_level[self.ground_cell[i] as usize];
        put(z - g[0]);
        put(z - g[1]);
        put(z - g[2]);
        put(inp.non_last.map_or(-1.0, |m| f32::from(u8::from(m[i]))));
        put(inp.returns.map_or(-1.0, |r| f32::from(r[i])));
        put(inp.intensity.map_or(-1.0, |v| v[i]));
        for r in 0..RULES.len() {
            put(if inp.rule[i] as usize == r { 1.0 } else { 0.0 });
        }
        debug_assert_eq!(k, feature_count());
    }
}

/// A point's position in finest-voxel units (local coordinates).
fn fine_q(p: &[f64; 3]) -> [f64; 3] {
    p.map(|v| v / SCALES[0])
}

/// Lowest corner of the dual cell at scale `s > 0` of the points in finest voxel `k`: the
/// centres of the scale's voxels lie at `n K + n / 2` finest units (n = 2^s), so the dual
/// cell's corners are `floor((q − n/2) / n)` and `+ 1` — for every q in the finest voxel.
fn coarse_base(k: &[i64; 3], s: usize) -> [i64; 3] {
    let n = 1i64 << s;
    k.map(|v| (v - n / 2).div_euclid(n))
}

/// The dual cell of a point at `q` (finest units) at scale `s`, and the point's place in it
/// (0..1 per axis, the trilinear weights). Computed by the same operations when the cells
/// are built and when a row is read, so both agree to the bit.
fn dual_cell(q: &[f64; 3], s: usize) -> ([i64; 3], [f32; 3]) {
    if s == 0 {
        let u = q.map(|v| v - 0.5);
        let b = u.map(|v| v.floor() as i64);
        (
            b,
            std::array::from_fn(|c| (u[c] - b[c] as f64).clamp(0.0, 1.0) as f32),
        )
    } else {
        let n = (1i64 << s) as f64;
        let b = coarse_base(&q.map(|v| v.floor() as i64), s);
        let f =
            std::array::from_fn(|c| ((q[c] - n / 2.0) / n - b[c] as f64).clamp(0.0, 1.0) as f32);
        (b, f)
    }
}

/// A scale's statistics at a point: trilinear weights over the occupied corners of its dual
/// cell, renormalised; a value that is undefined (−1) at a corner is averaged over the
/// corners where it is defined (−1 when none is). The point's own voxel is always one of the
/// corners, with weight ≥ 1/8, so a row never reads nothing.
fn interpolate(sc: &Scale, corners: &[u32; 8], f: [f32; 3]) -> [f32; 10] {
    let mut sum = [0.0f32; 10];
    let mut weight = [0.0f32; 10];
    for (c, &v) in corners.iter().enumerate() {
        if v == NONE {
            continue;
        }
        let w = (0..3)
            .map(|a| if c >> a & 1 == 1 { f[a] } else { 1.0 - f[a] })
            .product::<f32>();
        let st = &sc.stats[v as usize];
        for j in 0..10 {
            // Mean, min and max z (6..=8) are always defined; the others use −1 for "none".
            if (6..=8).contains(&j) || st[j] >= 0.0 {
                sum[j] += w * st[j];
                weight[j] += w;
            }
        }
    }
    std::array::from_fn(|j| {
        if weight[j] > 0.0 {
            sum[j] / weight[j]
        } else {
            -1.0
        }
    })
}

/// Shapes of the groups (segments or objects) of `ids` (0: no group).
fn group_shapes(ids: &[u32], hag: &[f64], local: &[[f64; 3]]) -> HashMap<u32, SegShape> {
    // Per group: n, sums of x, y, z, the 6 second moments; z min/max, height sum and max.
    let mut acc: HashMap<u32, ([f64; 10], f64, f64, f64, f64)> = HashMap::new();
    for (i, p) in local.iter().enumerate() {
        let s = ids[i];
        if s == 0 {
            continue;
        }
        let e = acc.entry(s).or_insert((
            [0.0; 10],
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.0,
            f64::NEG_INFINITY,
        ));
        let m = &mut e.0;
        m[0] += 1.0;
        m[1] += p[0];
        m[2] += p[1];
        m[3] += p[2];
        m[4] += p[0] * p[0];
        m[5] += p[0] * p[1];
        m[6] += p[0] * p[2];
        m[7] += p[1] * p[1];
        m[8] += p[1] * p[2];
        m[9] += p[2] * p[2];
        e.1 = e.1.min(p[2]);
        e.2 = e.2.max(p[2]);
        e.3 += hag[i];
        e.4 = e.4.max(hag[i]);
    }
    acc.into_iter()
        .map(|(s, (m, zmin, zmax, hsum, hmax))| {
            let n = m[0];
            let mu = [m[1] / n, m[2] / n, m[3] / n];
            let cxx = m[4] / n - mu[0] * mu[0];
            let cxy = m[5] / n - mu[0] * mu[1];
            let cxz = m[6] / n - mu[0] * mu[2];
            let cyy = m[7] / n - mu[1] * mu[1];
            let cyz = m[8] / n - mu[1] * mu[2];
            let czz = m[9] / n - mu[2] * mu[2];
            let (vals, vecs) =
                crate::geom::sym3_eigen([[cxx, cxy, cxz], [cxy, cyy, cyz], [cxz, cyz, czz]]);
            let nz = if n >= 3.0 && vals[2] > 0.0 {
                vecs[0][2].abs()
            } else {
                -1.0
            };
            let half = 0.5 * (cxx + cyy);
            let disc = (0.25 * (cxx - cyy).powi(2) + cxy * cxy).sqrt();
            let major = (half + disc).max(0.0).sqrt();
            let minor = (half - disc).max(0.0).sqrt();
            (
                s,
                [
                    n.ln_1p() as f32,
                    nz as f32,
                    (zmax - zmin) as f32,
                    major as f32,
                    minor as f32,
                    (hsum / n) as f32,
                    hmax as f32,
                ],
            )
        })
        .collect()
}

/// The ground-level grid: per [`GROUND_CELL`] cell (coarser on sparse data) the lowest ground point, then sliding
/// minima over 2 m and 5 m and the maximum over 2 m (separable: rows, then columns). Kerbs
/// and height steps show as the difference between a point and the lowest ground nearby.
fn ground_levels(local: &[[f64; 3]], is_ground: &[bool]) -> (Vec<u32>, Vec<[f32; 3]>) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in local {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    if local.is_empty() {
        return (Vec::new(), Vec::new());
    }
    // Cell edges on the world grid (local coordinates start at a corner of it; every cell
    // size below divides 8 m), so a cell holds the same points whatever the tile.
    let lo = lo.map(|v| (v / 8.0).floor() * 8.0);
    // The grid is dense over the bounding box: on sparse data (under 2 points per m²) its
    // cells double until there are at most two per point, so its memory stays within the
    // per-point charge. The size then follows the density, not the tile's extent.
    let mut size = GROUND_CELL;
    let dims = |size: f64| {
        let n = |d: f64| ((d / size) as usize + 1).min(1 << 13);
        (n(hi[0] - lo[0]), n(hi[1] - lo[1]))
    };
    while dims(size).0 * dims(size).1 > 2 * local.len() && size < 8.0 {
        size *= 2.0;
    }
    let (nx, ny) = dims(size);
    let cell: Vec<u32> = local
        .iter()
        .map(|p| {
            let ix = (((p[0] - lo[0]) / size) as usize).min(nx - 1);
            let iy = (((p[1] - lo[1]) / size) as usize).min(ny - 1);
            (iy * nx + ix) as u32
        })
        .collect();
    let mut zmin = vec![f32::INFINITY; nx * ny];
    let mut zmax = vec![f32::NEG_INFINITY; nx * ny];
    for (i, p) in local.iter().enumerate() {
        if is_ground[i] {
            let c = cell[i] as usize;
            zmin[c] = zmin[c].min(p[2] as f32);
            zmax[c] = zmax[c].max(p[2] as f32);
        }
    }
    let slide = |v: &[f32], r: usize, max: bool| -> Vec<f32> {
        let pick = |a: f32, b: f32| if max { a.max(b) } else { a.min(b) };
        let mut rows = v.to_vec();
        for y in 0..ny {
            for x in 0..nx {
                let (a, b) = (x.saturating_sub(r), (x + r).min(nx - 1));
                rows[y * nx + x] = v[y * nx + a..=y * nx + b]
                    .iter()
                    .copied()
                    .fold(v[y * nx + x], pick);
            }
        }
        let mut out = rows.clone();
        for y in 0..ny {
            let (a, b) = (y.saturating_sub(r), (y + r).min(ny - 1));
            for x in 0..nx {
                out[y * nx + x] = (a..=b)
                    .map(|yy| rows[yy * nx + x])
                    .fold(rows[y * nx + x], pick);
            }
        }
        out
    };
    let r2 = ((2.0 / size).round() as usize).max(1);
    let r5 = ((5.0 / size).round() as usize).max(1);
    let (min2, min5, max2) = (
        slide(&zmin, r2, false),
        slide(&zmin, r5, false),
        slide(&zmax, r2, true),
    );
    let level = (0..nx * ny)
        .map(|c| {
            let f = |v: f32| if v.is_finite() { v } else { f32::NAN };
            [f(min2[c]), f(min5[c]), f(max2[c])]
        })
        .collect();
    (cell, level)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ground_level_grid_coarsens_on_sparse_points() {
        // Four points over 1 km²: 0.5 m cells would be 4 M; the grid stops at 8 m cells.
        let local = [
            [0.0, 0.0, 0.0],
            [1000.0, 0.0, 1.0],
            [0.0, 1000.0, 2.0],
            [1000.0, 1000.0, 3.0],
        ];
        let (cell, level) = ground_levels(&local, &[true; 4]);
        assert!(level.len() <= 126 * 126, "{}", level.len());
        // Each corner is alone within 5 m: its own height is the lowest ground nearby.
        for (i, p) in local.iter().enumerate() {
            assert_eq!(level[cell[i] as usize][1], p[2] as f32);
        }
        // Dense points keep 0.5 m cells: 10 × 10 m at 100 points per m².
        let dense: Vec<[f64; 3]> = (0..10_000)
            .map(|k| [(k % 100) as f64 * 0.1, (k / 100) as f64 * 0.1, 0.0])
            .collect();
        let (_, level) = ground_levels(&dense, &vec![true; dense.len()]);
        assert_eq!(level.len(), 20 * 20);
    }

    #[test]
    fn names_match_rows_and_shapes_are_told_apart() {
        assert_eq!(feature_names().len(), feature_count());
        // A horizontal plane and a vertical line.
        let mut xyz = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                xyz.push([i as f64 * 0.05, j as f64 * 0.05, 0.0]);
            }
        }
        let plane = xyz.len();
        for k in 0..100 {
            xyz.push([2.5, 1.0, k as f64 * 0.05]);
        }
        let n = xyz.len();
        let hag: Vec<f64> = xyz.iter().map(|p| p[2]).collect();
        let g: Vec<bool> = (0..n).map(|i| i < plane).collect();
        let seg = vec![0u32; n];
        let rule = vec![0u8; n];
        let inp = DescribeInput {
            xyz: &xyz,
            hag: &hag,
            is_ground: &g,
            segment: &seg,
            object: &seg,
            rule: &rule,
            non_last: None,
            returns: None,
            intensity: None,
        };
        let d = Descriptors::new(&inp, &vec![true; n]);
        let mut r = vec![0.0; feature_count()];
        // Scale 0.4 m (index 2): planarity of the plane, linearity of the line.
        d.row(20 * 40 + 20, &mut r);
        assert!(r[2 * 10 + 2] > 0.9, "planarity {}", r[2 * 10 + 2]);
        assert!(r[2 * 10 + 4] > 0.99, "normal_z {}", r[2 * 10 + 4]);
        d.row(plane + 50, &mut r);
        assert!(r[2 * 10 + 1] > 0.9, "linearity {}", r[2 * 10 + 1]);
        assert!(r[2 * 10 + 5] > 0.99, "axis_z {}", r[2 * 10 + 5]);
        assert!(r.iter().all(|v| v.is_finite()));
        // Above the lowest ground within 2 m: the line's point at 2.5 m.
        assert!(
            (r[feature_names()
                .iter()
                .position(|n| n == "above_ground_min_2m")
                .unwrap()]
                - 2.5)
                .abs()
                < 1e-3
        );
    }

    /// Rows of `xyz` (all points classified) with no segments, objects or returns.
    fn rows(xyz: &[[f64; 3]], of: &[usize]) -> Vec<Vec<f32>> {
        let n = xyz.len();
        let hag: Vec<f64> = xyz.iter().map(|p| p[2]).collect();
        let g: Vec<bool> = xyz.iter().map(|p| p[2] < 0.01).collect();
        let zeros = vec![0u32; n];
        let rule = vec![0u8; n];
        let inp = DescribeInput {
            xyz,
            hag: &hag,
            is_ground: &g,
            segment: &zeros,
            object: &zeros,
            rule: &rule,
            non_last: None,
            returns: None,
            intensity: None,
        };
        let d = Descriptors::new(&inp, &vec![true; n]);
        of.iter()
            .map(|&i| {
                let mut r = vec![0.0; feature_count()];
                d.row(i, &mut r);
                r
            })
            .collect()
    }

    /// A 16 × 10 m ground plane at 0.1 m spacing with a 6 m wall along x = 11 m, placed at
    /// `x0, y0` in the world.
    fn plane_and_wall(x0: f64, y0: f64) -> Vec<[f64; 3]> {
        let mut xyz = Vec::new();
        for i in 0..160 {
            for j in 0..100 {
                xyz.push([x0 + i as f64 * 0.1 + 0.05, y0 + j as f64 * 0.1 + 0.05, 0.0]);
            }
        }
        for j in 0..100 {
            for k in 1..60 {
                xyz.push([x0 + 11.0, y0 + j as f64 * 0.1 + 0.05, k as f64 * 0.1]);
            }
        }
        xyz
    }

    #[test]
    fn features_do_not_jump_where_a_voxel_edge_falls() {
        // Two points 0.2 mm apart on either side of x = 6.4 m, an edge of the 3.2 m voxels:
        // the block of the voxel on the right reaches the wall at 11 m (12 of its 27 voxels
        // occupied), that of the voxel on the left does not (9). Read from one voxel, the
        // coarse occupancy jumped by 3 / 27 there; interpolated, both points sit half-way
        // between the two voxels' centres and read 10.5 / 27, and every feature agrees.
        let mut xyz = plane_and_wall(0.0, 0.0);
        let (a, b) = (xyz.len(), xyz.len() + 1);
        xyz.push([6.4 - 1e-4, 4.8, 0.0]);
        xyz.push([6.4 + 1e-4, 4.8, 0.0]);
        let r = rows(&xyz, &[a, b]);
        let names = feature_names();
        let per_scale = SCALES.len() * PER_SCALE.len();
        for ((name, u), v) in names.iter().zip(&r[0]).zip(&r[1]).take(per_scale) {
            assert!((u - v).abs() < 0.01, "{name}: {u} and {v}");
        }
        let occupancy = 5 * PER_SCALE.len();
        for row in &r {
            assert!(
                (row[occupancy] - 10.5 / 27.0).abs() < 0.01,
                "{}",
                row[occupancy]
            );
        }
    }

    #[test]
    fn rows_do_not_depend_on_the_first_point_or_far_points() {
        // The grids are anchored to the world: the same points after a cluster 35 m away (a
        // tile reaching further, and another first point, which the grids followed before)
        // give the same rows bit for bit.
        let (x0, y0) = (120_003.7, 484_951.3);
        let xyz = plane_and_wall(x0, y0);
        let probe = [0, 8_050, 15_999, 16_000 + 1_450];
        let first = rows(&xyz, &probe);
        let mut other: Vec<[f64; 3]> = (0..50)
            .map(|k| [x0 + 51.0 + k as f64 * 0.01, y0 + 1.0, 0.0])
            .collect();
        other.extend_from_slice(&xyz);
        let moved: Vec<usize> = probe.iter().map(|&i| i + 50).collect();
        assert_eq!(first, rows(&other, &moved));
    }
}
