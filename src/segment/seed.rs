//! Seed-plane detection and acceptance (thesis §3.5.3, Table 3-1 "Seed Plane Selection").
//!
//! A plane is first *detected* among the unlabelled neighbours of the seed point — by a 3D
//! Hough transform in normal form (eq. 2.3: normal angles θ, φ and distance d, bins `a_b` and
//! `d_b`) or by RANSAC — then refitted by least squares to the points within `d_ths` and
//! accepted only if all criteria of §3.5.3 hold.

use std::f64::consts::{FRAC_PI_2, PI};

use super::features::{cdist, fit_plane, orient, Plane};
use super::{SeedMethod, SegParams};

/// Discretisation of the unit hemisphere of normal directions into rings of equal polar width
/// `a_b` (angle φ from the horizontal, eq. 2.3) and, on each ring, azimuth (θ) bins whose
/// width in arc length is about `a_b` too — so all bins cover about the same solid angle.
///
/// A plane and its flipped normal are the same plane, so only the upper hemisphere is kept;
/// on the bottom ring (near-vertical planes, near-horizontal normals) θ is folded to [0, π)
/// so a wall whose noisy normals straddle the horizon does not split its votes in two.
#[derive(Debug, Clone)]
pub struct HoughGrid {
    ab: f64,
    ring_start: Vec<u32>,
    ring_bins: Vec<u32>,
    /// Bin-centre normals, indexed by bin key (used by the exhaustive transform).
    centres: Vec<[f64; 3]>,
}

impl HoughGrid {
    /// Grid for an angular bin of `a_b_deg` degrees.
    pub fn new(a_b_deg: f64) -> Self {
        let ab = a_b_deg.to_radians().clamp(1e-3, FRAC_PI_2);
        let rings = (FRAC_PI_2 / ab).ceil() as usize;
        let mut ring_start = Vec::with_capacity(rings);
        let mut ring_bins = Vec::with_capacity(rings);
        let mut centres = Vec::new();
        for r in 0..rings {
            let phi = ((r as f64 + 0.5) * ab).min(FRAC_PI_2);
            let span = if r == 0 { PI } else { 2.0 * PI };
            let nb = ((span * phi.cos() / ab).round() as u32).max(1);
            ring_start.push(centres.len() as u32);
            ring_bins.push(nb);
            for b in 0..nb {
                let th = (b as f64 + 0.5) * span / nb as f64;
                centres.push([th.cos() * phi.cos(), th.sin() * phi.cos(), phi.sin()]);
            }
        }
        HoughGrid {
            ab,
            ring_start,
            ring_bins,
            centres,
        }
    }

    /// Bin key of a unit normal.
    pub fn key(&self, n: [f64; 3]) -> u32 {
        let n = if n[2] < 0.0 { [-n[0], -n[1], -n[2]] } else { n };
        let phi = n[2].clamp(0.0, 1.0).asin();
        let r = ((phi / self.ab) as usize).min(self.ring_bins.len() - 1);
        // `+ 0.0` turns -0.0 into +0.0 so both signs of a pole normal share a bin.
        let mut th = (n[1] + 0.0).atan2(n[0] + 0.0);
        if th < 0.0 {
            th += 2.0 * PI;
        }
        let span = if r == 0 {
            th %= PI;
            PI
        } else {
            2.0 * PI
        };
        let nb = self.ring_bins[r];
        let b = ((th / span * nb as f64) as u32).min(nb - 1);
        self.ring_start[r] + b
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.centres.len()
    }

    /// True when the grid has no bins (never, for a valid angle).
    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }
}

/// Reusable buffers for seed detection.
#[derive(Debug, Default)]
pub struct Scratch {
    rel: Vec<[f64; 3]>,
    votes: Vec<(u32, u32)>,
    dbins: Vec<i64>,
    inl: Vec<u32>,
}

/// Hough transform restricted to planes through the seed point: every pair of neighbours
/// spans, with the seed, one plane whose normal votes for one (θ, φ) bin; d is the seed's own
/// distance bin. This is the randomized-Hough idea (three points → one vote) with all pairs
/// enumerated instead of sampled, so it is deterministic. Restricting d loses nothing the
/// acceptance test would keep: §3.5.3 rejects every plane farther than `d_ths` from the seed.
/// Cost: k²/2 votes instead of k × (number of orientation bins) for the per-point transform.
fn hough_seed_pairs(
    seed: [f64; 3],
    cand: &[u32],
    pts: &[[f64; 3]],
    grid: &HoughGrid,
    s: &mut Scratch,
) -> Option<Plane> {
    s.rel.clear();
    s.rel.extend(cand.iter().map(|&j| {
        let p = pts[j as usize];
        [p[0] - seed[0], p[1] - seed[1], p[2] - seed[2]]
    }));
    s.votes.clear();
    // Pairs nearly collinear with the seed give unstable normals: require ≥ 15° between them.
    let sin_min2 = 15f64.to_radians().sin().powi(2);
    for a in 0..s.rel.len() {
        let u = s.rel[a];
        let uu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        for (b, v) in s.rel.iter().enumerate().skip(a + 1) {
            let c = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            let cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
            let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            if cc <= sin_min2 * uu * vv || cc == 0.0 {
                continue;
            }
            let inv = 1.0 / cc.sqrt();
            let key = grid.key([c[0] * inv, c[1] * inv, c[2] * inv]);
            s.votes.push((key, (a * 65536 + b) as u32));
        }
    }
    if s.votes.is_empty() {
        return None;
    }
    s.votes.sort_unstable();
    let (mut best, mut best_n, mut i) = (0usize, 0usize, 0usize);
    while i < s.votes.len() {
        let mut j = i + 1;
        while j < s.votes.len() && s.votes[j].0 == s.votes[i].0 {
            j += 1;
        }
        if j - i > best_n {
            best_n = j - i;
            best = i;
        }
        i = j;
    }
    // Plane normal: mean of the winning bin's normals, signs aligned with the first one.
    let mut acc = [0.0f64; 3];
    let mut first: Option<[f64; 3]> = None;
    for &(_, ab) in &s.votes[best..best + best_n] {
        let (a, b) = ((ab >> 16) as usize, (ab & 0xffff) as usize);
        let (u, v) = (s.rel[a], s.rel[b]);
        let c = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let l = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        let mut n = [c[0] / l, c[1] / l, c[2] / l];
        let f = *first.get_or_insert(n);
        if n[0] * f[0] + n[1] * f[1] + n[2] * f[2] < 0.0 {
            n = [-n[0], -n[1], -n[2]];
        }
        for k in 0..3 {
            acc[k] += n[k];
        }
    }
    let l = (acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]).sqrt();
    if l == 0.0 {
        return None;
    }
    let n = orient([acc[0] / l, acc[1] / l, acc[2] / l]);
    Some(Plane {
        n,
        d: n[0] * seed[0] + n[1] * seed[1] + n[2] * seed[2],
    })
}

/// The classic 3D Hough transform in normal form: every point (seed included) votes, for
/// every orientation bin, into the distance bin `round(n · p / d_b)`; the fullest
/// (θ, φ, d) cell wins. Distances are taken relative to the seed point.
fn hough_exhaustive(
    seed: [f64; 3],
    cand: &[u32],
    pts: &[[f64; 3]],
    grid: &HoughGrid,
    d_b: f64,
    s: &mut Scratch,
) -> Option<Plane> {
    s.rel.clear();
    s.rel.push([0.0; 3]);
    s.rel.extend(cand.iter().map(|&j| {
        let p = pts[j as usize];
        [p[0] - seed[0], p[1] - seed[1], p[2] - seed[2]]
    }));
    let inv = 1.0 / d_b;
    let mut best: Option<(usize, usize, i64)> = None; // (votes, orientation, d bin)
    for (o, n) in grid.centres.iter().enumerate() {
        s.dbins.clear();
        s.dbins.extend(
            s.rel
                .iter()
                .map(|p| ((n[0] * p[0] + n[1] * p[1] + n[2] * p[2]) * inv).round() as i64),
        );
        s.dbins.sort_unstable();
        let mut i = 0;
        while i < s.dbins.len() {
            let mut j = i + 1;
            while j < s.dbins.len() && s.dbins[j] == s.dbins[i] {
                j += 1;
            }
            if best.is_none_or(|b| j - i > b.0) {
                best = Some((j - i, o, s.dbins[i]));
            }
            i = j;
        }
    }
    let (_, o, db) = best?;
    let n = grid.centres[o];
    let d = n[0] * seed[0] + n[1] * seed[1] + n[2] * seed[2] + db as f64 * d_b;
    Some(Plane { n, d })
}

/// SplitMix64: a tiny deterministic generator (RANSAC samples are seeded by the seed point's
/// canonical index, so runs repeat exactly).
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// RANSAC (Fischler & Bolles): planes through three sampled points, scored by the number of
/// points within `d_ths`; the best wins (first on ties).
fn ransac(
    seed_idx: usize,
    cand: &[u32],
    pts: &[[f64; 3]],
    d_ths: f64,
    iters: usize,
) -> Option<Plane> {
    let m = cand.len();
    if m < 3 {
        return None;
    }
    let mut st = seed_idx as u64 ^ 0xA076_1D64_78BD_642F;
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..iters {
        let a = (splitmix(&mut st) % m as u64) as usize;
        let b = (splitmix(&mut st) % m as u64) as usize;
        let c = (splitmix(&mut st) % m as u64) as usize;
        if a == b || b == c || a == c {
            continue;
        }
        let (p, q, r) = (
            pts[cand[a] as usize],
            pts[cand[b] as usize],
            pts[cand[c] as usize],
        );
        let Some(pl) = Plane::through(&p, &q, &r, 1e-12) else {
            continue;
        };
        let count = cand
            .iter()
            .filter(|&&j| pl.dist(&pts[j as usize]) < d_ths)
            .count();
        if best.as_ref().is_none_or(|b| count > b.0) {
            best = Some((count, pl));
        }
    }
    best.map(|b| b.1)
}

/// Tries to grow a seed plane around point `seed`. `cand` holds the seed's unlabelled
/// neighbours within `r_seed` (not the seed itself). Returns the refitted plane and its
/// points (seed included) if every §3.5.3 criterion holds:
/// at least `n_min` points within `d_ths`, seed within `d_ths`, and — with colour — seed
/// colour within `c_ths` of the plane's mean colour and total colour variance (eq. 3.5)
/// below `c_ths²` (eq. 3.4).
pub fn seed_plane(
    seed: usize,
    cand: &[u32],
    pts: &[[f64; 3]],
    lab: Option<&[[f32; 3]]>,
    p: &SegParams,
    grid: &HoughGrid,
    s: &mut Scratch,
) -> Option<(Plane, Vec<u32>)> {
    if cand.len() + 1 < p.n_min.max(3) {
        return None;
    }
    let sp = pts[seed];
    let detected = match p.seed_method {
        SeedMethod::Hough => hough_seed_pairs(sp, cand, pts, grid, s)?,
        SeedMethod::HoughExhaustive => hough_exhaustive(sp, cand, pts, grid, p.d_b_m, s)?,
        SeedMethod::Ransac => {
            s.inl.clear();
            s.inl.push(seed as u32);
            s.inl.extend_from_slice(cand);
            ransac(seed, &s.inl, pts, p.d_ths_m, p.ransac_iters)?
        }
    };
    let all = std::iter::once(seed as u32).chain(cand.iter().copied());
    // Refit to the points within d_ths of the detected plane, then count again (§3.5.3).
    s.inl.clear();
    s.inl.extend(
        all.clone()
            .filter(|&j| detected.dist(&pts[j as usize]) < p.d_ths_m),
    );
    if s.inl.len() < 3 {
        return None;
    }
    let (plane, _) = fit_plane(pts, s.inl.iter().copied())?;
    let inl: Vec<u32> = all
        .filter(|&j| plane.dist(&pts[j as usize]) < p.d_ths_m)
        .collect();
    if inl.len() < p.n_min || plane.dist(&sp) >= p.d_ths_m {
        return None;
    }
    if let Some(lab) = lab {
        let inv = 1.0 / inl.len() as f64;
        let mut mean = [0.0f64; 3];
        for &j in &inl {
            for (c, m) in mean.iter_mut().enumerate() {
                *m += lab[j as usize][c] as f64 * inv;
            }
        }
        let var: f64 = inl
            .iter()
            .map(|&j| {
                let d = cdist(&lab[j as usize], &mean);
                d * d * inv
            })
            .sum();
        if cdist(&lab[seed], &mean) >= p.c_ths || var >= p.c_ths * p.c_ths {
            return None;
        }
    }
    Some((plane, inl))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy_plane_with_outliers() -> Vec<[f64; 3]> {
        // Tilted plane z = 0.3 x - 0.2 y plus a second, perpendicular plane (an edge).
        let mut pts = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
                let e = ((i * 7 + j * 3) % 5) as f64 * 0.002;
                pts.push([x, y, 0.3 * x - 0.2 * y + e]);
            }
        }
        for j in 0..8 {
            pts.push([0.3, j as f64 * 0.04, 0.2 + j as f64 * 0.03]);
        }
        pts
    }

    #[test]
    fn grid_keys_cover_hemisphere() {
        let g = HoughGrid::new(3.0);
        assert!(g.len() > 2000 && g.len() < 2600, "{}", g.len());
        for (k, c) in g.centres.iter().enumerate() {
            assert_eq!(g.key(*c) as usize, k, "centre {c:?}");
        }
        // Flipped normals and near-horizon normals on both sides share a bin.
        assert_eq!(g.key([0.0, 0.0, 1.0]), g.key([0.0, 0.0, -1.0]));
        assert_eq!(g.key([0.6, 0.8, 0.001]), g.key([-0.6, -0.8, 0.001]));
    }

    #[test]
    fn all_detectors_find_the_dominant_plane() {
        let pts = noisy_plane_with_outliers();
        let cand: Vec<u32> = (1..pts.len() as u32).collect();
        let grid = HoughGrid::new(3.0);
        let truth = {
            let l = (0.09f64 + 0.04 + 1.0).sqrt();
            [-0.3 / l, 0.2 / l, 1.0 / l]
        };
        for m in [
            SeedMethod::Hough,
            SeedMethod::HoughExhaustive,
            SeedMethod::Ransac,
        ] {
            let p = SegParams {
                seed_method: m,
                n_min: 20,
                d_ths_m: 0.02,
                ..SegParams::tls()
            };
            let mut s = Scratch::default();
            let (pl, inl) = seed_plane(0, &cand, &pts, None, &p, &grid, &mut s)
                .unwrap_or_else(|| panic!("{m:?} found nothing"));
            let dot: f64 = (0..3).map(|c| pl.n[c] * truth[c]).sum();
            assert!(dot.abs() > 0.999, "{m:?}: {pl:?}");
            assert_eq!(inl.len(), 36, "{m:?}");
        }
    }
}
