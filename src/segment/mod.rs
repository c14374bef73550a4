//! Segmentation of (coloured) point clouds into planar segments by region growing on geometry
//! and CIELab colour — Sapkota (2008), *Segmentation of Coloured Point Cloud Data* (the
//! "thesis" below) — with a smoothness-constraint mode (Rabbani et al. 2006) for curved
//! surfaces.
//!
//! Stages (thesis Table 3-1), each in its own module:
//! 1. [`neighbours`]: `k` nearest neighbours within a radius for every point (voxel grid or
//!    kd-tree).
//! 2. [`features`]: 8/16-bit colour detection, vector median filter (§3.4), CIELab (§3.5.2),
//!    local normals/curvature, least-squares planes.
//! 3. [`seed`]: seed planes by 3D Hough transform or RANSAC, accepted by §3.5.3.
//! 4. [`grow`]: plane growing with local/global colour tests, edge reassignment and the
//!    eligible list (§3.5.4).
//!
//! **Determinism.** Points are first put in a canonical order (Morton code of the coordinates
//! quantised on a fixed 1 mm grid, then the exact coordinates); neighbour lists break distance
//! ties by that order, seeds are visited by ascending local curvature then that order, and
//! growing is sequential. The output therefore does not depend on the input order or on the
//! number of rayon threads (only exact duplicate coordinates fall back to input order).
//! Segment ids are numbered 1..=N by each segment's first point in canonical order.
//!
//! **Subsets agree.** The canonical order compares two points by their own coordinates only,
//! and [`segment_at`] computes in coordinates relative to a caller-given origin: so two calls
//! on overlapping point sets (a tile with its buffer, and its neighbour) see the same
//! neighbour lists, curvatures and tie-breaks for the points they share away from the edges
//! of their sets. Quantising relative to each set's bounding box, or centring on it, changed
//! tie-breaks between f32-equal neighbour distances and made tiled runs disagree with an
//! untiled run on ~5 % of the points of a real mobile-mapping tile (cm-quantised
//! coordinates are full of exact distance ties).

pub mod features;
pub mod grow;
pub mod multicue;
pub mod neighbours;
pub mod seed;

use std::fmt;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use crate::model::SegmentInfo;
pub use features::{rgb_is_8bit, rgb_to_lab, LabFormula};

/// How regions grow.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Planar segments: seed planes plus distance-to-plane growing (thesis §3.5).
    Planar,
    /// Smoothness constraint (Rabbani et al. 2006): a neighbour joins when its local normal
    /// is within `angle_deg` of the current point's; it continues the growth only when its
    /// curvature (surface variation) is below `curvature`.
    Smooth {
        /// Maximum angle between neighbouring normals, degrees.
        angle_deg: f64,
        /// Maximum surface variation λ0 / (λ0 + λ1 + λ2) of points that keep growing.
        curvature: f64,
    },
}

/// Seed-plane detector (thesis §3.5.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SeedMethod {
    /// Hough transform in normal form over planes through the seed point, voted by point
    /// pairs (fast; see `seed::hough_seed_pairs`).
    Hough,
    /// Classic per-point 3D Hough transform over all (θ, φ, d) bins (slow; reference).
    HoughExhaustive,
    /// RANSAC with `ransac_iters` deterministic samples.
    Ransac,
}

/// Neighbour search structure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NeighbourSearch {
    /// The faster one as measured (the voxel grid; see [`neighbours`]).
    Auto,
    /// `kiddo::ImmutableKdTree`.
    KdTree,
    /// Hashed voxel grid with data-adaptive cells.
    VoxelGrid,
}

/// Parameters of [`segment`]. Names follow thesis §3.6; distances in metres, colour distances
/// in CIELab units (ΔE*ab). The presets cite the tables of thesis chapter 4.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SegParams {
    /// Nearest neighbours per point (`k`).
    pub k: usize,
    /// Minimum number of points in a seed plane (`n`).
    pub n_min: usize,
    /// Neighbourhood radius for seed selection (`r_ths`).
    pub r_seed_m: f64,
    /// Neighbourhood radius for growing (`r_thg`).
    pub r_grow_m: f64,
    /// Hough distance bin (`d_b`; exhaustive Hough only).
    pub d_b_m: f64,
    /// Hough angle bin (`a_b`).
    pub a_b_deg: f64,
    /// Maximum distance of a point to the seed plane (`d_ths`).
    pub d_ths_m: f64,
    /// Maximum distance of a point to the growing plane (`d_thg`).
    pub d_thg_m: f64,
    /// Maximum colour distance of the seed to its plane's mean (`℘_ths`); the seed plane's
    /// colour variance must stay below its square (eq. 3.4).
    pub c_ths: f64,
    /// Maximum colour distance to the local region mean while growing (`℘_thl`).
    pub c_thl: f64,
    /// Maximum colour distance to the global region mean while growing (`℘_thg`).
    pub c_thg: f64,
    /// Refit the growing plane after this many additions (§3.5.4 "Adjustment of plane
    /// parameters"; the thesis gives no value).
    pub refit_every: usize,
    /// Use colour (false = geometry only, thesis §4.5).
    pub colour: bool,
    /// Vector median filter before segmentation (§3.4, §4.3).
    pub vector_median: bool,
    /// Window of the vector median filter: the point and its `vmf_k - 1` nearest neighbours.
    pub vmf_k: usize,
    /// RGB → CIELab formula.
    pub lab: LabFormula,
    /// Planar or smoothness-constraint growing.
    pub mode: Mode,
    /// Seed-plane detector.
    pub seed_method: SeedMethod,
    /// RANSAC samples per seed.
    pub ransac_iters: usize,
    /// Planes meeting at more than this angle are "edge segments" whose border points may be
    /// reassigned (§3.5.4).
    pub edge_angle_deg: f64,
    /// Neighbours (besides the point) in the RMS of the edge test.
    pub edge_k: usize,
    /// Segments smaller than this are dissolved (points get label 0) at the end.
    pub min_segment_points: usize,
    /// Neighbour search.
    pub search: NeighbourSearch,
}

impl Default for SegParams {
    fn default() -> Self {
        SegParams::tls()
    }
}

impl SegParams {
    /// Terrestrial laser scanning, ~2 cm spacing: German building data of the thesis —
    /// k = 20 (Table 4-1), n = 10 (Table 4-2), radii 0.25 / 0.25 m (Table 4-3), distances
    /// 0.08 / 0.08 m (Table 4-4), colour 8 / 8 / 20 (Table 4-5), Hough bins 0.1 m and 3°
    /// (§4.4.1), vector median over 10 neighbours (§4.3).
    pub fn tls() -> Self {
        SegParams {
            k: 20,
            n_min: 10,
            r_seed_m: 0.25,
            r_grow_m: 0.25,
            d_b_m: 0.1,
            a_b_deg: 3.0,
            d_ths_m: 0.08,
            d_thg_m: 0.08,
            c_ths: 8.0,
            c_thl: 8.0,
            c_thg: 20.0,
            refit_every: 50,
            colour: true,
            vector_median: true,
            vmf_k: 10,
            lab: LabFormula::Srgb,
            mode: Mode::Planar,
            seed_method: SeedMethod::Hough,
            ransac_iters: 60,
            edge_angle_deg: 20.0,
            edge_k: 4,
            min_segment_points: 10,
            search: NeighbourSearch::Auto,
        }
    }

    /// Airborne laser scanning, ~10 pts/m²: ITC building data — k = 20 (Table 4-1), n = 8
    /// (Table 4-2), radii 1.5 / 1.75 m (Table 4-3), distances 0.20 / 0.25 m (Table 4-4),
    /// colour 10 / 10 / 15 (Table 4-5), Hough bins 0.1 m and 3° (§4.4.1), vector median over
    /// 5 neighbours (§4.3).
    pub fn als() -> Self {
        SegParams {
            n_min: 8,
            r_seed_m: 1.5,
            r_grow_m: 1.75,
            d_ths_m: 0.20,
            d_thg_m: 0.25,
            c_ths: 10.0,
            c_thl: 10.0,
            c_thg: 15.0,
            vmf_k: 5,
            min_segment_points: 8,
            ..SegParams::tls()
        }
    }

    /// Mobile mapping (not in the thesis): the Vlaardingen TLS values — radii 0.15 / 0.20 m
    /// (Table 4-3), distances 0.08 / 0.08 m (Table 4-4), colour 8 / 8 / 20 (Table 4-5) —
    /// because street-level mobile scans have TLS-like spacing and noise near the vehicle.
    /// The vector median filter is off: it erodes colour features thinner than about half
    /// its window (window frames; measured on the synthetic buildings, see config).
    pub fn mobile() -> Self {
        SegParams {
            r_seed_m: 0.15,
            r_grow_m: 0.20,
            vector_median: false,
            ..SegParams::tls()
        }
    }

    /// Checks ranges; says which parameter is wrong.
    pub fn validate(&self) -> Result<(), SegError> {
        let pos = [
            ("r_seed_m", self.r_seed_m),
            ("r_grow_m", self.r_grow_m),
            ("d_b_m", self.d_b_m),
            ("a_b_deg", self.a_b_deg),
            ("d_ths_m", self.d_ths_m),
            ("d_thg_m", self.d_thg_m),
            ("c_ths", self.c_ths),
            ("c_thl", self.c_thl),
            ("c_thg", self.c_thg),
        ];
        for (name, v) in pos {
            if !(v.is_finite() && v > 0.0) {
                return Err(SegError::Param(format!("{name} must be > 0, got {v}")));
            }
        }
        if self.k < 3 || self.k > 1000 {
            return Err(SegError::Param(format!(
                "k must be in 3..=1000, got {}",
                self.k
            )));
        }
        if self.refit_every == 0 {
            return Err(SegError::Param("refit_every must be ≥ 1".into()));
        }
        if self.a_b_deg > 90.0 {
            return Err(SegError::Param(format!(
                "a_b_deg must be ≤ 90, got {}",
                self.a_b_deg
            )));
        }
        if let Mode::Smooth {
            angle_deg,
            curvature,
        } = self.mode
        {
            if !(angle_deg > 0.0 && angle_deg < 90.0) || curvature.is_nan() {
                return Err(SegError::Param(format!(
                    "smooth mode needs 0 < angle_deg < 90 and a curvature, got {angle_deg}, {curvature}"
                )));
            }
        }
        Ok(())
    }
}

/// Errors of [`segment`].
#[derive(Debug, Clone, PartialEq)]
pub enum SegError {
    /// A parameter is out of range.
    Param(String),
    /// A per-point array has the wrong length.
    Length {
        /// Which array.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The number of points.
        expected: usize,
    },
}

impl fmt::Display for SegError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SegError::Param(m) => write!(f, "invalid segmentation parameter: {m}"),
            SegError::Length {
                what,
                got,
                expected,
            } => write!(
                f,
                "{what} has {got} entries, expected one per point ({expected})"
            ),
        }
    }
}

impl std::error::Error for SegError {}

/// Counters and stage timings of one call.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SegStats {
    /// Points that took part.
    pub points: usize,
    /// Seed planes tried.
    pub seeds_tried: usize,
    /// Points attached from the eligible list.
    pub eligible_attached: usize,
    /// Wall time of: ordering, neighbours, normals, colour, growing, output (seconds).
    pub stage_s: [f64; 6],
}

/// Result of [`segment`].
#[derive(Debug, Clone, PartialEq)]
pub struct SegOutput {
    /// Segment id per input point, 0 = none (masked out or not in any segment).
    pub labels: Vec<u32>,
    /// Segments by id (`segments[i].id == i + 1`).
    pub segments: Vec<SegmentInfo>,
    /// Counters and timings.
    pub stats: SegStats,
}

/// Spreads the low 21 bits of `v` three apart (Morton interleave).
fn spread3(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Segments the points `xyz` (with optional colour and optional participation mask) into
/// planar (or smooth) segments.
///
/// Points with non-finite coordinates, or whose mask entry is false, get label 0 and are not
/// used. Colour is used when `rgb` is given and `p.colour` is set; 8-bit values stored in
/// 16-bit fields are detected with [`rgb_is_8bit`]. Computes relative to the centre of the
/// points' bounding box; see [`segment_at`] for sets that must agree with each other.
pub fn segment(
    xyz: &[[f64; 3]],
    rgb: Option<&[[u16; 3]]>,
    mask: Option<&[bool]>,
    p: &SegParams,
) -> Result<SegOutput, SegError> {
    segment_at(xyz, rgb, mask, p, None)
}

/// [`segment`] computing in coordinates relative to `origin` (default: the centre of the
/// points' bounding box). Tiles of one run pass one run-wide origin, so the geometry of the
/// points they share is computed bit for bit alike (inputs are projected coordinates of
/// 1e5–1e6 m; f64 keeps ~1e-10 m there, the origin only has to be the same).
pub fn segment_at(
    xyz: &[[f64; 3]],
    rgb: Option<&[[u16; 3]]>,
    mask: Option<&[bool]>,
    p: &SegParams,
    origin: Option<[f64; 3]>,
) -> Result<SegOutput, SegError> {
    p.validate()?;
    let n_in = xyz.len();
    if let Some(c) = rgb.filter(|c| c.len() != n_in) {
        return Err(SegError::Length {
            what: "rgb",
            got: c.len(),
            expected: n_in,
        });
    }
    if let Some(m) = mask.filter(|m| m.len() != n_in) {
        return Err(SegError::Length {
            what: "mask",
            got: m.len(),
            expected: n_in,
        });
    }
    let mut stage = [0.0f64; 6];
    let t0 = Instant::now();
    let (active, pts, centre) = canonical_order(xyz, mask, origin);
    stage[0] = t0.elapsed().as_secs_f64();

    let t = Instant::now();
    let radius = p.r_seed_m.max(p.r_grow_m);
    let nb = match p.search {
        NeighbourSearch::KdTree => neighbours::knn_kdtree(&pts, p.k, radius),
        NeighbourSearch::Auto | NeighbourSearch::VoxelGrid => {
            neighbours::knn_voxel(&pts, p.k, radius)
        }
    };
    stage[1] = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let normals = features::normals(&pts, &nb, p.r_grow_m);
    stage[2] = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let scale = rgb.map(|c| if rgb_is_8bit(c) { 255.0 } else { 65535.0 });
    let lab = colour_lab(rgb.zip(scale), &active, &nb, p);
    stage[3] = t.elapsed().as_secs_f64();

    let t = Instant::now();
    // Seeds by ascending (curvature, index).
    let order = crate::geom::ascending_by_f32(normals.iter().map(|nv| nv.1));
    let inp = grow::Input {
        pts: &pts,
        lab: lab.as_deref(),
        nb: &nb,
        normals: &normals,
        order: &order,
    };
    let grown = grow::grow(&inp, p);
    stage[4] = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let (labels, segments) = segment_output(&grown, &active, &pts, centre, (rgb, scale), n_in, p);
    stage[5] = t.elapsed().as_secs_f64();
    Ok(SegOutput {
        labels,
        segments,
        stats: SegStats {
            points: pts.len(),
            seeds_tried: grown.seeds_tried,
            eligible_attached: grown.eligible_attached,
            stage_s: stage,
        },
    })
}

/// The points taking part (mask true, finite coordinates) in canonical order, their
/// coordinates relative to the centre, and the centre (`origin`, else the bounding-box
/// centre).
fn canonical_order(
    xyz: &[[f64; 3]],
    mask: Option<&[bool]>,
    origin: Option<[f64; 3]>,
) -> (Vec<u32>, Vec<[f64; 3]>, [f64; 3]) {
    // Canonical order. Without an origin, centre on the bounding-box centre (min/max do not
    // depend on point order, a summed centroid would).
    let mut active: Vec<u32> = (0..xyz.len() as u32)
        .filter(|&i| {
            mask.is_none_or(|m| m[i as usize]) && xyz[i as usize].iter().all(|v| v.is_finite())
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for &i in &active {
        for c in 0..3 {
            lo[c] = lo[c].min(xyz[i as usize][c]);
            hi[c] = hi[c].max(xyz[i as usize][c]);
        }
    }
    let centre: [f64; 3] = origin.unwrap_or(std::array::from_fn(|c| 0.5 * (lo[c] + hi[c])));
    // Morton code on a fixed absolute 1 mm grid, wrapping every 2^21 mm (~2 km): the key of
    // a point depends on nothing else, so every subset orders its points alike; locality
    // (the reason for Morton order) only breaks at the wrap lines.
    let mut keyed: Vec<(u64, u32)> = active
        .iter()
        .map(|&i| {
            let p = &xyz[i as usize];
            let q = |c: usize| ((p[c] * 1000.0).floor() as i64 & 0x1f_ffff) as u64;
            (
                spread3(q(0)) | (spread3(q(1)) << 1) | (spread3(q(2)) << 2),
                i,
            )
        })
        .collect();
    keyed.par_sort_unstable_by(|&(ka, a), &(kb, b)| {
        ka.cmp(&kb)
            .then_with(|| {
                let (pa, pb) = (&xyz[a as usize], &xyz[b as usize]);
                pa[0]
                    .total_cmp(&pb[0])
                    .then(pa[1].total_cmp(&pb[1]))
                    .then(pa[2].total_cmp(&pb[2]))
            })
            .then(a.cmp(&b))
    });
    active = keyed.into_iter().map(|(_, i)| i).collect();
    let pts: Vec<[f64; 3]> = active
        .iter()
        .map(|&i| {
            let p = xyz[i as usize];
            [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
        })
        .collect();
    (active, pts, centre)
}

/// CIELab colour per point (in canonical order) when `p.colour` is set, from the input colour
/// and its full scale (255 or 65535), vector-median filtered if asked.
fn colour_lab(
    rgb: Option<(&[[u16; 3]], f64)>,
    active: &[u32],
    nb: &neighbours::Neighbours,
    p: &SegParams,
) -> Option<Vec<[f32; 3]>> {
    let rgb01: Option<Vec<[f32; 3]>> = rgb.map(|(c, s)| {
        active
            .iter()
            .map(|&i| c[i as usize].map(|v| (v as f64 / s) as f32))
            .collect()
    });
    rgb01.as_ref().filter(|_| p.colour).map(|c01| {
        let filtered;
        let src = if p.vector_median {
            filtered = features::vector_median(c01, nb, p.vmf_k);
            &filtered
        } else {
            c01
        };
        src.par_iter()
            .map(|c| rgb_to_lab(c.map(f64::from), p.lab).map(|v| v as f32))
            .collect()
    })
}

/// Dissolves small segments, numbers the rest by their first point in canonical order and
/// describes them: the label per input point and the segments. `(rgb, scale)` are the input
/// colour and its full scale.
fn segment_output(
    grown: &grow::Grown,
    active: &[u32],
    pts: &[[f64; 3]],
    centre: [f64; 3],
    (rgb, scale): (Option<&[[u16; 3]]>, Option<f64>),
    n_in: usize,
    p: &SegParams,
) -> (Vec<u32>, Vec<SegmentInfo>) {
    let mut count = vec![0usize; grown.segs.len() + 1];
    for &l in &grown.labels {
        count[l as usize] += 1;
    }
    let mut remap = vec![0u32; grown.segs.len() + 1];
    let mut next = 0u32;
    for &l in &grown.labels {
        let l = l as usize;
        if l != 0 && remap[l] == 0 && count[l] >= p.min_segment_points.max(1) {
            next += 1;
            remap[l] = next;
        }
    }
    let nseg = next as usize;
    let mut mom: Vec<Option<features::Moments>> = vec![None; nseg];
    let mut csum = vec![[0.0f64; 3]; nseg];
    let mut labels = vec![0u32; n_in];
    for (k, &l) in grown.labels.iter().enumerate() {
        let id = remap[l as usize];
        if id == 0 {
            continue;
        }
        let s = id as usize - 1;
        let i = active[k] as usize;
        labels[i] = id;
        mom[s]
            .get_or_insert_with(|| features::Moments::new(pts[k]))
            .add(&pts[k]);
        if let (Some(c), Some(sc)) = (rgb, scale) {
            for ch in 0..3 {
                csum[s][ch] += c[i][ch] as f64 * 255.0 / sc;
            }
        }
    }
    let segments = mom
        .iter()
        .zip(&csum)
        .enumerate()
        .map(|(s, (m, cs))| {
            let m = m.as_ref();
            let npts = m.map_or(0, |m| m.n);
            let (plane, rms) = m.and_then(|m| m.plane()).unwrap_or((
                features::Plane {
                    n: [0.0, 0.0, 1.0],
                    d: 0.0,
                },
                0.0,
            ));
            let nrm = plane.n;
            let d = plane.d + nrm[0] * centre[0] + nrm[1] * centre[1] + nrm[2] * centre[2];
            SegmentInfo {
                id: s as u32 + 1,
                n: npts,
                normal: nrm,
                d,
                mean_rgb: cs.map(|v| v / npts.max(1) as f64),
                rms,
            }
        })
        .collect();
    (labels, segments)
}
