//! Ground subclasses (street-level document, chapter 5 §9): region growing on the ground points
//! with normal-angle, curvature and CIELab colour criteria; small regions merged into the
//! neighbouring region with the nearest a*b* mean (lightness left out because of shadows,
//! §9.1); regions classified by training samples (§9.2, [`super::samples`]); kNN majority
//! smoothing of the labels (§9.2.6).

use super::samples::SampleSet;
use crate::segment::neighbours::Neighbours;
use serde::{Deserialize, Serialize};

/// Parameters of the ground labelling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroundLabelParams {
    /// Neighbours per point.
    pub k: usize,
    /// Neighbourhood radius, metres.
    pub radius_m: f64,
    /// Ground points farther than this outside a tile's core get no subclass there (their
    /// neighbours, normals and regions are most of the label stage's work); never less than
    /// `radius_m` (a core point's neighbourhood is always whole), capped by `label.context_m`,
    /// which the cheaper object labelling uses. See [`GroundLabelParams::context`].
    pub context_m: f64,
    /// Largest angle between the normals of neighbouring points in one region, degrees
    /// (document: 45).
    pub angle_deg: f64,
    /// Points with a surface variation above this join a region but do not grow it further.
    pub curvature: f64,
    /// Largest CIELab distance of a joining point to its region's mean colour.
    pub colour_region: f64,
    /// Largest CIELab distance between a joining point and the region point it is reached from.
    pub colour_local: f64,
    /// Regions smaller than this are merged into the neighbouring region with the nearest
    /// a*b* mean (document §9.1 used 5000 points on a far denser, larger scene).
    pub min_region_points: usize,
    /// Standard deviations around a sample's mean that accept a region (document: 3).
    pub sigma: f64,
    /// Floor of a sample's standard deviation, CIELab units (a perfectly uniform sample would
    /// otherwise accept nothing but itself).
    pub min_std: f64,
    /// Neighbours in the majority smoothing (0: no smoothing).
    pub smooth_k: usize,
    /// A neighbour further than this from the tangent plane of the point it is reached from
    /// does not join (a kerb step ends a region); 0 = no limit. Colour separates kerbs in
    /// coloured scans; geometry-only runs need this.
    pub max_step_m: f64,
    /// Without training samples: road / sidewalk / terrain from kerbs and roughness
    /// ([`super::kerbs`]) instead of the unknown code for every region.
    pub geometry: bool,
    /// Kerb rise between road and sidewalk, metres (geometry mode).
    pub kerb_min_m: f64,
    /// Largest kerb rise, metres (geometry mode).
    pub kerb_max_m: f64,
    /// Paved (road, sidewalk) regions: mean surface variation at most this (geometry mode).
    pub rough_variation: f64,
    /// Paved regions: mean |n_z| at least this (geometry mode).
    pub level_nz: f64,
    /// Codes of road, sidewalk and terrain (geometry mode).
    pub geometry_codes: [u8; 3],
}

impl Default for GroundLabelParams {
    fn default() -> Self {
        GroundLabelParams {
            k: 12,
            radius_m: 0.35,
            context_m: 0.5,
            angle_deg: 45.0,
            curvature: 0.05,
            colour_region: 12.0,
            colour_local: 12.0,
            min_region_points: 50,
            sigma: 3.0,
            min_std: 1.0,
            smooth_k: 10,
            max_step_m: 0.0,
            geometry: false,
            kerb_min_m: 0.05,
            kerb_max_m: 0.35,
            rough_variation: 0.01,
            level_nz: 0.95,
            geometry_codes: [11, 65, 67],
        }
    }
}

impl GroundLabelParams {
    /// The ground subclasses' context beyond a tile's core, metres: `context_m`, at least
    /// `radius_m` so that every core point's neighbourhood (hence its normal) is whole,
    /// capped by the stage's context `cap` (`label.context_m`).
    pub fn context(&self, cap: f64) -> f64 {
        self.context_m.max(self.radius_m).min(cap)
    }
}

/// Result for the ground points given to [`label_ground`].
#[derive(Debug, Clone, Default)]
pub struct GroundLabels {
    /// Region per point after merging (1..), 0 when the point joined no region.
    pub region: Vec<u32>,
    /// Class code per point (`unknown` where no sample matched).
    pub class: Vec<u8>,
    /// Regions after merging.
    pub regions: usize,
    /// Regions before merging.
    pub regions_grown: usize,
    /// Regions (after merging) that no sample accepted.
    pub regions_unknown: usize,
}

struct Region {
    n: usize,
    lab: [f64; 3],
}

impl Region {
    fn mean(&self) -> [f64; 3] {
        let n = self.n.max(1) as f64;
        self.lab.map(|v| v / n)
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// Labels ground points. `normals` are (unit normal, surface variation) per point, `lab` the
/// CIELab colour (None: geometry only, every region is `unknown` unless no samples are
/// needed), `xyz` the positions (needed for `max_step_m`), `nb` the neighbour lists of these
/// points (sorted by distance), `samples` the classifier (None: unsupervised, every region
/// `unknown`).
pub fn label_ground(
    normals: &[([f32; 3], f32)],
    lab: Option<&[[f64; 3]]>,
    xyz: Option<&[[f64; 3]]>,
    nb: &Neighbours,
    samples: Option<&SampleSet>,
    unknown: u8,
    p: &GroundLabelParams,
) -> GroundLabels {
    let n = normals.len();
    let r2 = (p.radius_m * p.radius_m) as f32;
    // 1. Region growing, seeds by ascending surface variation (flattest first).
    let (region, mut regions) = grow_regions(normals, lab, xyz, nb, p);
    let grown = regions.len() - 1;

    // 2. Merge small regions into the adjacent region with the nearest a*b* mean (§9.1),
    // smallest first; a merged region that is still small keeps merging. With training
    // samples, a region a sample accepts keeps its own class however small it is (§9.2
    // classifies the grown regions): only regions no sample accepts are merged. Merging
    // everything small first put thin asphalt strips beside the kerb into the footpath
    // (a*b* ignores the lightness that tells them apart).
    let classify = |r: &Region| match (samples, lab) {
        (Some(s), Some(_)) => s.classify(&r.mean(), p.sigma, p.min_std),
        _ => None,
    };
    let pre_class: Vec<Option<u8>> = regions.iter().map(&classify).collect();
    let mut parent: Vec<u32> = (0..regions.len() as u32).collect();
    let mut adj = adjacency(&region, regions.len(), nb, r2);
    // Geometry mode judges every region on its own roughness and kerbs (merging by a*b*
    // means nothing without colour); smoothing then cleans the fragments.
    let merge_small = !(p.geometry && samples.is_none());
    let mut small: Vec<u32> = (1..regions.len() as u32)
        .filter(|&r| {
            merge_small
                && regions[r as usize].n < p.min_region_points
                && pre_class[r as usize].is_none()
        })
        .collect();
    small.sort_by_key(|&r| (regions[r as usize].n, r));
    for r in small {
        let r = find(&mut parent, r);
        if regions[r as usize].n >= p.min_region_points {
            continue;
        }
        merge_region(
            r,
            &mut regions,
            &mut adj,
            &mut parent,
            &pre_class,
            p.min_region_points,
        );
    }
    // Final region numbering 1.. in order of first point.
    let mut renum = vec![0u32; regions.len()];
    let mut next = 0u32;
    let mut out_region = vec![0u32; n];
    for i in 0..n {
        if region[i] == 0 {
            continue;
        }
        let root = find(&mut parent, region[i]) as usize;
        if renum[root] == 0 {
            next += 1;
            renum[root] = next;
        }
        out_region[i] = renum[root];
    }

    // 3. Supervised classification of each region by its mean colour.
    let mut class_of_root = vec![unknown; regions.len()];
    let mut unknown_regions = 0;
    for (root, &num) in renum.iter().enumerate() {
        if num == 0 {
            continue;
        }
        let c = pre_class[root].or_else(|| classify(&regions[root]));
        if c.is_none() {
            unknown_regions += 1;
        }
        class_of_root[root] = c.unwrap_or(unknown);
    }
    let mut class: Vec<u8> = (0..n)
        .map(|i| {
            if region[i] == 0 {
                unknown
            } else {
                class_of_root[find(&mut parent, region[i]) as usize]
            }
        })
        .collect();

    // 4. kNN majority smoothing (§9.2.6).
    smooth_labels(&mut class, nb, p.smooth_k);
    GroundLabels {
        region: out_region,
        class,
        regions: next as usize,
        regions_grown: grown,
        regions_unknown: unknown_regions,
    }
}

/// Region growing (step 1 of [`label_ground`]), seeds by ascending surface variation
/// (flattest first). Returns the region per point (0: none) and the regions (index 0 is the
/// empty "no region").
fn grow_regions(
    normals: &[([f32; 3], f32)],
    lab: Option<&[[f64; 3]]>,
    xyz: Option<&[[f64; 3]]>,
    nb: &Neighbours,
    p: &GroundLabelParams,
) -> (Vec<u32>, Vec<Region>) {
    let n = normals.len();
    let r2 = (p.radius_m * p.radius_m) as f32;
    let cos_a = p.angle_deg.to_radians().cos() as f32;
    let order = crate::geom::ascending_by_f32(normals.iter().map(|nv| nv.1));
    let mut region = vec![0u32; n];
    let mut regions: Vec<Region> = vec![Region {
        n: 0,
        lab: [0.0; 3],
    }];
    let mut queue = std::collections::VecDeque::new();
    let zero = [0.0; 3];
    for &s in &order {
        let s = s as usize;
        if region[s] != 0 || !normals[s].1.is_finite() {
            continue;
        }
        let id = regions.len() as u32;
        let c0 = lab.map_or(zero, |l| l[s]);
        regions.push(Region { n: 1, lab: c0 });
        region[s] = id;
        queue.push_back(s as u32);
        while let Some(a) = queue.pop_front() {
            let a = a as usize;
            let na = normals[a].0;
            for &b in nb.within(a, r2) {
                let b = b as usize;
                if region[b] != 0 || !normals[b].1.is_finite() {
                    continue;
                }
                let nbv = normals[b].0;
                let dot = (na[0] * nbv[0] + na[1] * nbv[1] + na[2] * nbv[2]).abs();
                if dot < cos_a {
                    continue;
                }
                if let (Some(x), true) = (xyz, p.max_step_m > 0.0) {
                    let d: f64 = (0..3).map(|k| na[k] as f64 * (x[b][k] - x[a][k])).sum();
                    if d.abs() > p.max_step_m {
                        continue;
                    }
                }
                if let Some(l) = lab {
                    let r = &regions[id as usize];
                    if dist(&l[b], &r.mean()) > p.colour_region
                        || dist(&l[b], &l[a]) > p.colour_local
                    {
                        continue;
                    }
                }
                region[b] = id;
                let r = &mut regions[id as usize];
                r.n += 1;
                if let Some(l) = lab {
                    for (acc, v) in r.lab.iter_mut().zip(&l[b]) {
                        *acc += v;
                    }
                }
                if normals[b].1 <= p.curvature as f32 {
                    queue.push_back(b as u32);
                }
            }
        }
    }
    (region, regions)
}

/// The regions adjacent to each region (sorted, without duplicates): regions of the
/// neighbours within the radius (squared: `r2`) of its points.
fn adjacency(region: &[u32], n_regions: usize, nb: &Neighbours, r2: f32) -> Vec<Vec<u32>> {
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n_regions];
    for a in 0..region.len() {
        let ra = region[a];
        if ra == 0 {
            continue;
        }
        for &b in nb.within(a, r2) {
            let rb = region[b as usize];
            if rb != 0 && rb != ra {
                adj[ra as usize].push(rb);
            }
        }
    }
    for l in &mut adj {
        l.sort_unstable();
        l.dedup();
    }
    adj
}

/// Merges the small root region `r` into the adjacent region with the nearest a*b* mean (step
/// 2 of [`label_ground`]), and that one on while it is still small and no sample accepts it.
/// `parent` are the union-find parents ([`find`]).
fn merge_region(
    r: u32,
    regions: &mut [Region],
    adj: &mut [Vec<u32>],
    parent: &mut [u32],
    pre_class: &[Option<u8>],
    min_region_points: usize,
) {
    let mut cur = r;
    loop {
        let me = regions[cur as usize].mean();
        let mut best: Option<(f64, u32)> = None;
        let cands: Vec<u32> = adj[cur as usize].clone();
        for c in cands {
            let c = find(parent, c);
            if c == cur {
                continue;
            }
            let o = regions[c as usize].mean();
            let d = ((me[1] - o[1]).powi(2) + (me[2] - o[2]).powi(2)).sqrt();
            if best.is_none_or(|b| d < b.0 || (d == b.0 && c < b.1)) {
                best = Some((d, c));
            }
        }
        let Some((_, t)) = best else { break };
        parent[cur as usize] = t;
        let (rn, rl) = (regions[cur as usize].n, regions[cur as usize].lab);
        let moved = std::mem::take(&mut adj[cur as usize]);
        let tr = &mut regions[t as usize];
        tr.n += rn;
        for (acc, v) in tr.lab.iter_mut().zip(&rl) {
            *acc += v;
        }
        adj[t as usize].extend(moved);
        if regions[t as usize].n >= min_region_points || pre_class[t as usize].is_some() {
            break;
        }
        cur = t;
    }
}

/// kNN majority smoothing of labels (§9.2.6), one pass over a snapshot with the first `k`
/// neighbours of each point; ties keep the point's own class when it is among the most
/// frequent, else the smallest code. `k` = 0: no smoothing.
pub fn smooth_labels(class: &mut [u8], nb: &Neighbours, k: usize) {
    if k > 0 {
        let snap = class.to_vec();
        let mut counts = [0u16; 256];
        for (i, c) in class.iter_mut().enumerate() {
            let nbs = nb.of(i);
            let nbs = &nbs[..nbs.len().min(k)];
            if nbs.is_empty() {
                continue;
            }
            counts[snap[i] as usize] += 1;
            for &j in nbs {
                counts[snap[j as usize] as usize] += 1;
            }
            let mut best = snap[i];
            for &j in nbs {
                let cj = snap[j as usize];
                let (a, b) = (counts[cj as usize], counts[best as usize]);
                if a > b || (a == b && cj < best && best != snap[i]) {
                    best = cj;
                }
            }
            counts[snap[i] as usize] = 0;
            for &j in nbs {
                counts[snap[j as usize] as usize] = 0;
            }
            *c = best;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::label::samples::Sample;
    use crate::segment::features::normals;
    use crate::segment::neighbours::knn_surface;

    #[test]
    fn ground_context_covers_a_neighbourhood_and_stays_within_the_stage_context() {
        let p = GroundLabelParams::default();
        assert_eq!(p.context(5.0), 0.5);
        // Narrower than the neighbourhood: widened to it, so core points keep all neighbours.
        let wide = GroundLabelParams {
            radius_m: 1.0,
            ..p.clone()
        };
        assert_eq!(wide.context(5.0), 1.0);
        // Never beyond the stage's own context.
        assert_eq!(wide.context(0.8), 0.8);
        assert_eq!(p.context(0.2), 0.2);
    }

    /// A flat 10 × 4 m strip, dark asphalt for x < 5 and red cycle path beyond, with colour
    /// noise and a shadowed patch of asphalt; samples for sunlit and shadowed asphalt kept
    /// apart and one for the cycle path.
    #[test]
    fn two_surfaces_and_a_shadow() {
        let mut pts = Vec::new();
        let mut lab = Vec::new();
        let mut truth = Vec::new();
        let mut h = 1u64;
        let mut rnd = || {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            (h >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for i in 0..200 {
            for j in 0..80 {
                let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
                pts.push([x, y, 0.002 * rnd()]);
                let (c, t) = if x < 5.0 {
                    let shade = if (2.0..3.0).contains(&x) { 0.6 } else { 1.0 };
                    ([45.0 * shade, 1.0, 3.0], 11u8)
                } else {
                    ([45.0, 35.0, 25.0], 64u8)
                };
                lab.push([c[0] + 2.0 * rnd(), c[1] + 2.0 * rnd(), c[2] + 2.0 * rnd()]);
                truth.push(t);
            }
        }
        let s = |class, mean: [f64; 3]| Sample {
            class,
            name: String::new(),
            points: 100,
            mean,
            std: [1.0; 3],
        };
        let set = SampleSet {
            samples: vec![
                s(11, [45.0, 1.0, 3.0]),
                s(11, [27.0, 1.0, 3.0]),
                s(64, [45.0, 35.0, 25.0]),
            ],
        };
        let p = GroundLabelParams::default();
        let nb = knn_surface(&pts, p.k, p.radius_m);
        let nrm = normals(&pts, &nb, p.radius_m);
        let out = label_ground(&nrm, Some(&lab), None, &nb, Some(&set), 2, &p);
        let ok = out.class.iter().zip(&truth).filter(|(a, b)| a == b).count();
        assert!(ok as f64 > 0.99 * pts.len() as f64, "{ok} of {}", pts.len());
        // Without the shadow sample the shadowed patch is unknown (2), not road.
        let set2 = SampleSet {
            samples: vec![set.samples[0].clone(), set.samples[2].clone()],
        };
        let out2 = label_ground(&nrm, Some(&lab), None, &nb, Some(&set2), 2, &p);
        let shadow_unknown = pts
            .iter()
            .zip(&out2.class)
            .filter(|(q, _)| (2.2..2.8).contains(&q[0]))
            .all(|(_, &c)| c == 2);
        assert!(shadow_unknown);
    }
}
