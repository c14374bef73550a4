//! Ground subclasses from geometry alone (no colour, no training samples): road, sidewalk and
//! terrain told apart by kerbs and roughness, for scans without RGB (vehicle LiDAR such as
//! SemanticKITTI) or runs without samples.
//!
//! The ground regions of [`super::label_ground`] (grown with a step limit, so a kerb ends a
//! region) are judged as a whole:
//! - a region is *paved* when it is smooth (mean surface variation ≤ `rough_variation`) and
//!   level (mean |n_z| ≥ `level_nz`); rough or sloping regions are terrain;
//! - the largest paved region is road — a mapping vehicle drives on it and sees it best;
//! - walking the region adjacency from the road: a paved neighbour across a rise of
//!   `kerb_min_m..=kerb_max_m` (median height difference along the shared border) is sidewalk,
//!   one at the same level continues the road (or the sidewalk it is reached from), and a
//!   drop of a kerb's height from a sidewalk leads back to road;
//! - paved regions not reached that way keep the unknown code.

use crate::segment::neighbours::Neighbours;

/// Codes and thresholds of the geometric classification.
#[derive(Debug, Clone, Copy)]
pub struct KerbRule {
    /// Smallest kerb rise between road and sidewalk, metres.
    pub kerb_min_m: f64,
    /// Largest kerb rise, metres.
    pub kerb_max_m: f64,
    /// Paved regions have a mean surface variation at most this.
    pub rough_variation: f64,
    /// Paved regions have a mean |n_z| at least this.
    pub level_nz: f64,
    /// Border point pairs two regions need to count as adjacent.
    pub min_border_pairs: usize,
    /// Codes: road, sidewalk, terrain, unknown.
    pub road: u8,
    /// Sidewalk code.
    pub sidewalk: u8,
    /// Terrain code.
    pub terrain: u8,
    /// Code of paved regions the rule cannot place.
    pub unknown: u8,
}

impl KerbRule {
    /// The rule of the geometry-mode parameters of `[label.ground]`, with `unknown` for paved
    /// regions it cannot place.
    pub fn from_params(p: &super::GroundLabelParams, unknown: u8) -> Self {
        let [road, sidewalk, terrain] = p.geometry_codes;
        KerbRule {
            kerb_min_m: p.kerb_min_m,
            kerb_max_m: p.kerb_max_m,
            rough_variation: p.rough_variation,
            level_nz: p.level_nz,
            min_border_pairs: 3,
            road,
            sidewalk,
            terrain,
            unknown,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Open,
    Road,
    Sidewalk,
}

/// Classes per point from the regions (`region[i]` in 1..=`n_regions`, 0 = none) of ground
/// points `xyz` with `normals` and neighbour lists `nb` (pairs within `sqrt(r2)` are borders).
pub fn classify_by_kerbs(
    xyz: &[[f64; 3]],
    normals: &[([f32; 3], f32)],
    nb: &Neighbours,
    r2: f32,
    region: &[u32],
    n_regions: usize,
    rule: &KerbRule,
) -> Vec<u8> {
    let m = n_regions + 1;
    let mut count = vec![0usize; m];
    let mut sv = vec![0f64; m];
    let mut nz = vec![0f64; m];
    for (i, &r) in region.iter().enumerate() {
        let (n, v) = normals[i];
        if r == 0 || !v.is_finite() {
            continue;
        }
        count[r as usize] += 1;
        sv[r as usize] += v as f64;
        nz[r as usize] += n[2].abs() as f64;
    }
    let paved: Vec<bool> = (0..m)
        .map(|r| {
            count[r] > 0
                && sv[r] / count[r] as f64 <= rule.rough_variation
                && nz[r] / count[r] as f64 >= rule.level_nz
        })
        .collect();
    // Height differences across borders, per ordered region pair (a < b): z_b − z_a.
    let mut border: std::collections::BTreeMap<(u32, u32), Vec<f32>> = Default::default();
    for (i, &ra) in region.iter().enumerate() {
        if ra == 0 {
            continue;
        }
        for &j in nb.within(i, r2) {
            let rb = region[j as usize];
            if rb == 0 || rb <= ra {
                continue;
            }
            let dz = (xyz[j as usize][2] - xyz[i][2]) as f32;
            border.entry((ra, rb)).or_default().push(dz);
        }
    }
    let mut adj: Vec<Vec<(u32, f64)>> = vec![Vec::new(); m];
    for ((a, b), mut d) in border {
        if d.len() < rule.min_border_pairs {
            continue;
        }
        d.sort_by(f32::total_cmp);
        let med = d[d.len() / 2] as f64;
        adj[a as usize].push((b, med));
        adj[b as usize].push((a, -med));
    }
    let mut kind = vec![Kind::Open; m];
    let road = (1..m)
        .filter(|&r| paved[r])
        .max_by_key(|&r| (count[r], std::cmp::Reverse(r)));
    if let Some(r0) = road {
        kind[r0] = Kind::Road;
        let mut queue = std::collections::VecDeque::from([r0]);
        while let Some(q) = queue.pop_front() {
            for &(t, dz) in &adj[q] {
                let t = t as usize;
                if kind[t] != Kind::Open || !paved[t] {
                    continue;
                }
                let level = dz.abs() < rule.kerb_min_m;
                let up = (rule.kerb_min_m..=rule.kerb_max_m).contains(&dz);
                let down = (rule.kerb_min_m..=rule.kerb_max_m).contains(&-dz);
                let next = match kind[q] {
                    Kind::Road if level => Kind::Road,
                    Kind::Road if up => Kind::Sidewalk,
                    Kind::Sidewalk if level => Kind::Sidewalk,
                    Kind::Sidewalk if down => Kind::Road,
                    _ => continue,
                };
                kind[t] = next;
                queue.push_back(t);
            }
        }
    }
    let class_of: Vec<u8> = (0..m)
        .map(|r| match kind[r] {
            Kind::Road => rule.road,
            Kind::Sidewalk => rule.sidewalk,
            Kind::Open if r > 0 && count[r] > 0 && !paved[r] => rule.terrain,
            Kind::Open => rule.unknown,
        })
        .collect();
    region.iter().map(|&r| class_of[r as usize]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::label::{label_ground, GroundLabelParams};
    use crate::segment::features::normals;
    use crate::segment::neighbours::knn_surface;

    /// A street cross-section: road for y < 0, a 0.15 m kerb, a sidewalk 0 ≤ y < 3, then a
    /// bumpy verge (terrain) beyond y = 3.
    #[test]
    fn road_kerb_sidewalk_verge() {
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        let mut h = 1u64;
        let mut rnd = || {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            (h % 10_000) as f64 / 10_000.0 - 0.5
        };
        for ix in 0..100 {
            for iy in -60..50 {
                let (x, y) = (ix as f64 * 0.1, iy as f64 * 0.1);
                let (z, c) = if y < 0.0 {
                    (0.02 * y, 11)
                } else if y < 3.0 {
                    (0.15 + 0.01 * y, 65)
                } else {
                    (0.18 + 0.12 * rnd() + 0.05 * (3.0 * x).sin(), 67)
                };
                pts.push([x, y, z + 0.002 * rnd()]);
                truth.push(c);
            }
        }
        let p = GroundLabelParams {
            max_step_m: 0.05,
            curvature: 0.01,
            geometry: true,
            ..Default::default()
        };
        let nb = knn_surface(&pts, p.k, p.radius_m);
        let nrm = normals(&pts, &nb, p.radius_m);
        let gl = label_ground(&nrm, None, Some(&pts), &nb, None, 2, &p);
        let rule = KerbRule {
            kerb_min_m: 0.05,
            kerb_max_m: 0.35,
            rough_variation: 0.01,
            level_nz: 0.95,
            min_border_pairs: 3,
            road: 11,
            sidewalk: 65,
            terrain: 67,
            unknown: 2,
        };
        let r2 = (p.radius_m * p.radius_m) as f32;
        let mut c = classify_by_kerbs(&pts, &nrm, &nb, r2, &gl.region, gl.regions, &rule);
        crate::label::ground::smooth_labels(&mut c, &nb, p.smooth_k);
        for code in [11u8, 65, 67] {
            let n = truth.iter().filter(|&&t| t == code).count();
            let ok = truth
                .iter()
                .zip(&c)
                .filter(|(&t, &g)| t == code && g == code)
                .count();
            assert!(ok as f64 >= 0.9 * n as f64, "class {code}: {ok} of {n}");
        }
    }
}
