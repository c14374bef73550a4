//! Per-scan segments tied into world segments inside a tile.
//!
//! Every point decoded from a drive with `segment.method = "multicue"` carries its scan's
//! segment as `scan << 24 | segment` ([`crate::io::mcap::SCAN_SEGMENT`]). Consecutive scans see
//! the same surfaces from a few decimetres further on, so the same object appears as one
//! segment in each; two such segments are the same world segment when they occupy the same
//! space. Space is a voxel grid: for scans `s` and `t` (consecutive among the scans present in
//! the tile), segment `a` of `s` and `b` of `t` are joined when
//! `n_ab ≥ min_shared_voxels` and `n_ab > majority_fraction · max(n_a, n_b)`,
//! where `n_ab` counts the voxels holding points of both, and `n_a` the voxels of `a` that scan
//! `t` observed at all (any of its points, segmented or not). That is the rule of the tile
//! stitching ([`crate::stitch::pairs`]) with voxels for shared points, counted in the space
//! both scans saw, so a segment is not kept apart just because the next scan sees less of it.
//!
//! Planar surfaces have a sharper test than shared space (`plane_tolerance_m`,
//! `colour_tolerance`): when the larger of two touching segments is planar, the smaller joins
//! it exactly when it lies on that plane with that colour — then without a majority (a
//! shadow moving along a façade splits it at a different place in each scan) and also
//! between two segments of one scan (split by the image, not by the surface); a window's
//! glass behind its façade, or the next building's façade in the same plane, stays apart.
//! A union–find over the (scan, segment) pairs joins them transitively along the drive; the
//! tile stitching then joins world segments across tile borders as for region growing.

use super::meanshift::UnionFind;
use super::refine::{dominant_plane, flat_and_wide, refine, sums, Members, RefineParams, Refined};
use crate::segment::features::{Moments, Plane};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

use crate::io::mcap::SCAN_SEGMENT_BITS as SEGMENT_BITS;

/// How per-scan segments are tied (`[segment.tie]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TieParams {
    /// Voxel edge, metres.
    pub voxel_m: f64,
    /// Least shared voxels for a tie.
    pub min_shared_voxels: usize,
    /// Shared voxels must exceed this share of the segments' voxels seen by the other scan …
    pub majority_fraction: f64,
    /// … of the larger of the two segments ("larger": one-to-one, as the tile stitching), or
    /// of the smaller ("smaller": a piece lying mostly inside a segment of the next scan joins
    /// it, so a scan that splits an object does not break its chain along the drive).
    pub basis: TieBasis,
    /// When the larger of two segments is a plane (RMS residual at most this, metres, and
    /// spread at least ten times that along both in-plane axes), the smaller joins it only if
    /// its points lie on that plane (RMS distance at most this): a window's glass a few
    /// centimetres behind its façade shares the façade's voxels but is not the façade.
    /// Non-planar or thin segments (vehicles, trees, poles) are not checked. 0: no check.
    pub plane_tolerance_m: f64,
    /// With the plane check, and when the points have colour: the smaller joins a planar
    /// segment only if their mean CIELab colours differ by at most this (ΔE*ab). Two
    /// buildings' façades in one plane share voxels where they meet; a scan's segments are
    /// uniform in colour already (the integration's colour veto), so a colour step between
    /// two of them on one plane is a boundary. 0: no check.
    pub colour_tolerance: f64,
    /// A world segment must hold segments of two scans or more, unless no other scan observed
    /// its voxels; otherwise its points are left unsegmented.
    pub confirm: bool,
    /// A segment that is not planar as a whole is still planar for the plane check when a
    /// plane holds at least this share of its points (within `plane_tolerance_m`; found by a
    /// seeded RANSAC, refitted to its inliers, wide as above): a scan's façade segment that
    /// took in the car parked in front of it or the footpath at its foot is still a façade,
    /// and a window's glass behind it is still not on it. 0: least-squares planes only (and
    /// no split in the refinement).
    pub dominant_fraction: f64,
    /// Voxel edge of the refinement of the world segments on the drive's points together
    /// (`refine.rs`: split off dominant planes, unsegmented points onto planes or into
    /// segments of their own, touching pieces of one surface or object joined), metres.
    /// 0: no refinement.
    pub refine_voxel_m: f64,
    /// In the refinement, a segment standing on a narrow vertical stem (within this radius of
    /// a vertical axis, metres) that carries something wider rising above it — a tree's trunk
    /// under its crown — gives the stem a segment of its own, and an upright round segment
    /// that narrow is enclosed only by another upright one (`refine.rs`). 0: no stems.
    pub stem_radius_m: f64,
    /// The least height of such a stem, and how far the rest must rise above its top, metres.
    pub stem_min_height_m: f64,
    /// In the refinement, a segment without a dominant plane whose points lie apart (no
    /// touching voxels of `voxel_m`) keeps its largest part; its other parts become segments
    /// of their own (`refine.rs`).
    pub split_apart: bool,
    /// In the refinement, the points on a world segment's dominant plane in two colours more
    /// than `colour_tolerance` apart, each filling a region of its own, are split by colour
    /// (two buildings' façades in one plane; `refine.rs`).
    pub split_colours: bool,
    /// In the refinement, unsegmented points attach to wide planes through points attached
    /// before them, pass by pass (a façade band no scan segmented joins its façade; `refine.rs`).
    pub attach_grows: bool,
}

/// Which segment's seen voxels the shared voxels are compared with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TieBasis {
    /// The larger of the two.
    Larger,
    /// The smaller of the two.
    Smaller,
}

impl Default for TieParams {
    fn default() -> Self {
        // 0.5 m: consecutive scans sample a surface at different places (ring spacing ~0.1 m
        // at 20 m on a 64-ring sensor, the vehicle moving ~1 m between scans), so voxels much
        // smaller than the ring spacing at range would rarely hold both.
        TieParams {
            voxel_m: 0.5,
            min_shared_voxels: 1,
            majority_fraction: 0.5,
            basis: TieBasis::Smaller,
            // 5 cm: a façade's own scatter passes, a window set 10 cm back does not.
            plane_tolerance_m: 0.05,
            colour_tolerance: 10.0,
            confirm: true,
            dominant_fraction: 0.6,
            refine_voxel_m: 0.25,
            // A trunk's or pole's radius with scatter (street trees 0.1–0.25 m).
            stem_radius_m: 0.3,
            stem_min_height_m: 1.0,
            split_apart: true,
            split_colours: true,
            attach_grows: true,
        }
    }
}

impl TieParams {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.voxel_m.is_finite() && self.voxel_m > 0.0) {
            return Err(format!(
                "segment.tie.voxel_m must be > 0, got {}",
                self.voxel_m
            ));
        }
        if !(self.plane_tolerance_m.is_finite() && self.plane_tolerance_m >= 0.0) {
            return Err(format!(
                "segment.tie.plane_tolerance_m must be >= 0, got {}",
                self.plane_tolerance_m
            ));
        }
        if !(self.colour_tolerance.is_finite() && self.colour_tolerance >= 0.0) {
            return Err(format!(
                "segment.tie.colour_tolerance must be >= 0, got {}",
                self.colour_tolerance
            ));
        }
        if !(self.dominant_fraction.is_finite() && (0.0..=1.0).contains(&self.dominant_fraction)) {
            return Err(format!(
                "segment.tie.dominant_fraction must be in [0, 1], got {}",
                self.dominant_fraction
            ));
        }
        if !(self.refine_voxel_m.is_finite() && self.refine_voxel_m >= 0.0) {
            return Err(format!(
                "segment.tie.refine_voxel_m must be >= 0, got {}",
                self.refine_voxel_m
            ));
        }
        if !(self.stem_radius_m.is_finite() && self.stem_radius_m >= 0.0) {
            return Err(format!(
                "segment.tie.stem_radius_m must be >= 0, got {}",
                self.stem_radius_m
            ));
        }
        if !(self.stem_min_height_m.is_finite() && self.stem_min_height_m > 0.0) {
            return Err(format!(
                "segment.tie.stem_min_height_m must be > 0, got {}",
                self.stem_min_height_m
            ));
        }
        if self.min_shared_voxels == 0 {
            return Err("segment.tie.min_shared_voxels must be >= 1".into());
        }
        if !(self.majority_fraction >= 0.0 && self.majority_fraction < 1.0) {
            return Err(format!(
                "segment.tie.majority_fraction must be in [0, 1), got {}",
                self.majority_fraction
            ));
        }
        Ok(())
    }
}

/// What tying found in one tile.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct TieStats {
    /// Scans with points in the tile.
    pub scans: usize,
    /// Per-scan segments with points in the tile.
    pub scan_segments: usize,
    /// Segment pairs of consecutive scans, or of one scan, sharing a voxel.
    pub candidate_pairs: usize,
    /// Pairs tied.
    pub ties: usize,
    /// World segments of one scan, where other scans looked, left unsegmented (`confirm`).
    pub unconfirmed: usize,
    /// Refinement (`refine.rs`): parts of world segments without a dominant plane that lay
    /// apart from the rest (`split_apart`) …
    pub apart: usize,
    /// … pieces split off world segments' dominant planes …
    pub split_off: usize,
    /// … stems split off the objects they carry (trunks under crowns) …
    pub stems: usize,
    /// … unsegmented points that joined a segment's plane …
    pub attached: usize,
    /// … and segments formed by the points left over.
    pub leftover_segments: usize,
    /// World segments (after ties) with points in the tile.
    pub world_segments: usize,
}

const NONE: u32 = u32::MAX;

/// Ties the per-scan segments of a tile's points into world segments.
///
/// `values` are the points' `scan_segment` values (0: the point has none); `observe` the
/// points whose voxels count as seen by their scan; `member` the points that belong to their
/// segment (a subset of `observe`, e.g. the non-ground ones); `lab` the points' CIELab colours
/// when they have colour. Returns the world segment per point (0 = none; 1.. numbered by first
/// point) and the figures.
pub fn tie(
    xyz: &[[f64; 3]],
    values: &[u64],
    observe: &[bool],
    member: &[bool],
    lab: Option<&[[f32; 3]]>,
    origin: [f64; 3],
    p: &TieParams,
) -> (Vec<u32>, TieStats) {
    let n = xyz.len();
    let local_mask = (1u64 << SEGMENT_BITS) - 1;
    // Dense scan ranks (drive order) and segment nodes.
    let mut scans: Vec<u64> = (0..n)
        .filter(|&i| observe[i] && values[i] != 0)
        .map(|i| values[i] >> SEGMENT_BITS)
        .collect();
    scans.sort_unstable();
    scans.dedup();
    let rank = |v: u64| scans.binary_search(&(v >> SEGMENT_BITS)).map(|r| r as u32);
    let mut node_of: HashMap<u64, u32> = HashMap::new();
    let mut node_value: Vec<u64> = Vec::new();
    let mut point_node = vec![NONE; n];
    // (voxel, scan rank, node) for every observed point.
    let mut entries: Vec<(u64, u32, u32)> = Vec::with_capacity(n);
    let inv = 1.0 / p.voxel_m;
    for i in 0..n {
        let v = values[i];
        if !observe[i] || v == 0 || !xyz[i].iter().all(|c| c.is_finite()) {
            continue;
        }
        let Ok(r) = rank(v) else { continue };
        let node = if member[i] && v & local_mask != 0 {
            *node_of.entry(v).or_insert_with(|| {
                node_value.push(v);
                node_value.len() as u32 - 1
            })
        } else {
            NONE
        };
        point_node[i] = node;
        let q = |c: usize| (((xyz[i][c] - origin[c]) * inv).floor() as i64 & 0x1f_ffff) as u64;
        entries.push((q(0) | q(1) << 21 | q(2) << 42, r, node));
    }
    entries.sort_unstable();
    entries.dedup();
    let nodes = node_value.len();
    let surfaces = Surfaces::new(xyz, &point_node, lab, nodes, origin, p);
    let Overlaps {
        seen_next,
        seen_prev,
        pairs,
        same,
    } = Overlaps::count(&entries, nodes);
    let mut uf = UnionFind::new(nodes);
    let mut ties = 0;
    for &((a, b), k) in &pairs {
        let (na, nb) = (seen_next[a as usize], seen_prev[b as usize]);
        let base = match p.basis {
            TieBasis::Larger => na.max(nb),
            TieBasis::Smaller => na.min(nb),
        } as f64;
        // A piece on a planar segment's plane, with its colour, is that surface wherever they
        // touch: no majority asked. A scan splits a façade where something in front of it
        // shadows it, and the shadow moves with the vehicle, so consecutive scans split it at
        // different places and their pieces overlap too little for a majority.
        let tied = match surfaces.on_plane(a, b) {
            Some(ok) => ok,
            None => k as usize >= p.min_shared_voxels && k as f64 > p.majority_fraction * base,
        };
        if tied {
            uf.union(a as usize, b as usize);
            ties += 1;
        }
    }
    // Two segments of one scan that touch are separate because the scan's image did not
    // connect them (a gap, an occluder in front): on one plane with one colour they are the
    // same surface too. Nothing else joins segments of one scan.
    for &((a, b), _) in &same {
        if surfaces.on_plane(a, b) == Some(true) {
            uf.union(a as usize, b as usize);
            ties += 1;
        }
    }
    let seen: Vec<bool> = (0..nodes)
        .map(|nd| seen_next[nd] + seen_prev[nd] > 0)
        .collect();
    let (mut labels, mut next, unconfirmed) =
        world_labels(&mut uf, &point_node, &node_value, &seen, p);
    let refined = if p.refine_voxel_m > 0.0 && p.plane_tolerance_m > 0.0 {
        let wanted: Vec<bool> = (0..n)
            .map(|i| member[i] && observe[i] && xyz[i].iter().all(|c| c.is_finite()))
            .collect();
        let rp = RefineParams {
            voxel_m: p.refine_voxel_m,
            plane_tolerance_m: p.plane_tolerance_m,
            dominant_fraction: p.dominant_fraction,
            colour_tolerance: p.colour_tolerance,
            stem_radius_m: p.stem_radius_m,
            stem_min_height_m: p.stem_min_height_m,
            apart_voxel_m: if p.split_apart { p.voxel_m } else { 0.0 },
            split_colours: p.split_colours,
            attach_grows: p.attach_grows,
        };
        let r = refine(xyz, &mut labels, next, &wanted, lab, origin, &rp);
        next = r.segments;
        r
    } else {
        Refined::default()
    };
    let stats = TieStats {
        scans: scans.len(),
        scan_segments: nodes,
        candidate_pairs: pairs.len() + same.len(),
        ties,
        unconfirmed,
        apart: refined.apart,
        split_off: refined.split_off,
        stems: refined.stems,
        attached: refined.attached,
        leftover_segments: refined.leftover_segments,
        world_segments: next as usize,
    };
    (labels, stats)
}

/// Per node, for the plane check (see [`TieParams::plane_tolerance_m`],
/// [`TieParams::dominant_fraction`] and [`TieParams::colour_tolerance`]): how many points it
/// has, its plane if it is planar, and the moments and mean colour of its surface — all its
/// points, or those on its dominant plane when only a dominant plane makes it planar (a
/// façade's segment with the car in front of it compares as the façade).
struct Surfaces {
    nodes: Vec<NodeSurface>,
    tol: f64,
    colour_tol: f64,
}

struct NodeSurface {
    points: usize,
    plane: Option<Plane>,
    surface: Moments,
    colour: Option<[f64; 3]>,
}

impl Surfaces {
    fn new(
        xyz: &[[f64; 3]],
        point_node: &[u32],
        lab: Option<&[[f32; 3]]>,
        nodes: usize,
        origin: [f64; 3],
        p: &TieParams,
    ) -> Self {
        let tol = p.plane_tolerance_m;
        let mut out = Surfaces {
            nodes: Vec::new(),
            tol,
            colour_tol: p.colour_tolerance,
        };
        if tol <= 0.0 {
            return out;
        }
        let lab = lab.filter(|_| p.colour_tolerance > 0.0);
        let members = Members::new(point_node, nodes);
        out.nodes = (0..nodes)
            .map(|nd| {
                let idx = members.of(nd);
                let (all, colour) = sums(xyz, idx, lab, origin);
                if let Some(plane) = flat_and_wide(&all, tol) {
                    return NodeSurface {
                        points: idx.len(),
                        plane: Some(plane),
                        surface: all,
                        colour,
                    };
                }
                match dominant_plane(xyz, idx, origin, tol, p.dominant_fraction) {
                    Some(plane) => {
                        let on_plane = idx.iter().filter(|&&i| plane.dist(&xyz[i as usize]) <= tol);
                        let (on, colour) = sums(xyz, on_plane, lab, origin);
                        NodeSurface {
                            points: idx.len(),
                            plane: Some(plane),
                            surface: on,
                            colour,
                        }
                    }
                    None => NodeSurface {
                        points: idx.len(),
                        plane: None,
                        surface: all,
                        colour,
                    },
                }
            })
            .collect();
        out
    }

    /// The plane check of a pair: `None` when the larger is not planar (or the check is off),
    /// else whether the smaller's surface lies on its plane with its colour.
    fn on_plane(&self, a: u32, b: u32) -> Option<bool> {
        let nodes = &self.nodes;
        if nodes.is_empty() {
            return None;
        }
        let (a, b) = (&nodes[a as usize], &nodes[b as usize]);
        let (big, small) = if a.points >= b.points { (a, b) } else { (b, a) };
        let plane = big.plane.as_ref()?;
        let near = small
            .surface
            .mean_sq_distance(plane)
            .is_none_or(|d2| d2.sqrt() <= self.tol);
        let same_colour = match (big.colour, small.colour) {
            (Some(x), Some(y)) => {
                let d2: f64 = (0..3).map(|c| (x[c] - y[c]).powi(2)).sum();
                d2.sqrt() <= self.colour_tol
            }
            _ => true,
        };
        Some(near && same_colour)
    }
}

/// Voxels shared by segments, from the sorted, deduplicated (voxel, scan rank, node) entries.
struct Overlaps {
    /// Per node, its voxels the next scan observed …
    seen_next: Vec<u32>,
    /// … and those the previous scan observed.
    seen_prev: Vec<u32>,
    /// Segment pairs of consecutive scans and their shared voxels, sorted.
    pairs: Vec<((u32, u32), u32)>,
    /// Segment pairs of one scan and their shared voxels, sorted.
    same: Vec<((u32, u32), u32)>,
}

impl Overlaps {
    fn count(entries: &[(u64, u32, u32)], nodes: usize) -> Self {
        let (mut seen_next, mut seen_prev) = (vec![0u32; nodes], vec![0u32; nodes]);
        let mut shared: HashMap<(u32, u32), u32> = HashMap::new();
        let mut same_scan: HashMap<(u32, u32), u32> = HashMap::new();
        for vox in entries.chunk_by(|a, b| a.0 == b.0) {
            // Scan ranks ascend within the voxel: each run is one scan.
            let runs: Vec<&[(u64, u32, u32)]> = vox.chunk_by(|a, b| a.1 == b.1).collect();
            for run in &runs {
                let segs: Vec<u32> = run.iter().map(|e| e.2).filter(|&x| x != NONE).collect();
                for (i, &a) in segs.iter().enumerate() {
                    for &b in &segs[i + 1..] {
                        *same_scan.entry((a, b)).or_default() += 1;
                    }
                }
            }
            for w in runs.windows(2) {
                let (s, t) = (w[0], w[1]);
                if t[0].1 != s[0].1 + 1 {
                    continue;
                }
                for a in s.iter().filter(|e| e.2 != NONE) {
                    seen_next[a.2 as usize] += 1;
                    for b in t.iter().filter(|e| e.2 != NONE) {
                        *shared.entry((a.2, b.2)).or_default() += 1;
                    }
                }
                for b in t.iter().filter(|e| e.2 != NONE) {
                    seen_prev[b.2 as usize] += 1;
                }
            }
        }
        let sorted = |m: HashMap<(u32, u32), u32>| {
            let mut v: Vec<((u32, u32), u32)> = m.into_iter().collect();
            v.sort_unstable();
            v
        };
        Overlaps {
            seen_next,
            seen_prev,
            pairs: sorted(shared),
            same: sorted(same_scan),
        }
    }
}

/// World segment per point from the union–find over nodes (numbered by first point), the
/// number of world segments, and how many were left unsegmented by [`TieParams::confirm`].
/// `seen`: per node, whether a neighbouring scan observed any of its voxels.
fn world_labels(
    uf: &mut UnionFind,
    point_node: &[u32],
    node_value: &[u64],
    seen: &[bool],
    p: &TieParams,
) -> (Vec<u32>, u32, usize) {
    let nodes = node_value.len();
    // Which world segments more than one scan found, and which lie where another scan looked.
    let mut first_scan = vec![u64::MAX; nodes];
    let (mut several, mut observed) = (vec![false; nodes], vec![false; nodes]);
    for nd in 0..nodes {
        let r = uf.find(nd);
        let sc = node_value[nd] >> SEGMENT_BITS;
        if first_scan[r] == u64::MAX {
            first_scan[r] = sc;
        } else if first_scan[r] != sc {
            several[r] = true;
        }
        observed[r] |= seen[nd];
    }
    let mut unconfirmed = 0;
    let mut world = vec![0u32; nodes];
    let mut next = 0u32;
    let mut labels = vec![0u32; point_node.len()];
    for (i, &nd) in point_node.iter().enumerate() {
        if nd == NONE {
            continue;
        }
        let root = uf.find(nd as usize);
        // A segment one scan found where its neighbours looked and found nothing like it is
        // a piece of that scan's own making (a few returns at an edge, split off by its
        // image), not a surface: the drive sees every surface from several scans. Kept where
        // no other scan looked (the drive's ends, a recording of one scan).
        if p.confirm && !several[root] && observed[root] {
            if world[root] == 0 {
                unconfirmed += 1;
                world[root] = u32::MAX;
            }
            continue;
        }
        if world[root] == 0 {
            next += 1;
            world[root] = next;
        }
        labels[i] = world[root];
    }
    (labels, next, unconfirmed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(scan: u64, seg: u64) -> u64 {
        scan << SEGMENT_BITS | seg
    }

    /// [`tie`] with every point observed and a member, at the origin.
    /// The ties' rules alone (no refinement, which `refine.rs` tests).
    fn ties_only() -> TieParams {
        TieParams {
            refine_voxel_m: 0.0,
            ..TieParams::default()
        }
    }

    fn tie_all(
        xyz: &[[f64; 3]],
        vals: &[u64],
        lab: Option<&[[f32; 3]]>,
        p: &TieParams,
    ) -> (Vec<u32>, TieStats) {
        let all = vec![true; xyz.len()];
        tie(xyz, vals, &all, &all, lab, [0.0; 3], p)
    }

    /// A wall seen by three scans as segments 1, 2 and 5, and a pole seen by the first two:
    /// the wall pieces tie, the pole ties with itself only, and a stray contact stays apart.
    #[test]
    fn consecutive_scans_tie_by_shared_voxels() {
        let mut xyz = Vec::new();
        let mut vals = Vec::new();
        for (scan, seg) in [(3u64, 1u64), (4, 2), (6, 5)] {
            for k in 0..40 {
                xyz.push([k as f64 * 0.25 + 0.01 * scan as f64, 0.0, 1.0]);
                vals.push(v(scan, seg));
            }
        }
        for (scan, seg) in [(3u64, 2u64), (4, 7)] {
            for k in 0..10 {
                xyz.push([20.0, 0.0, k as f64 * 0.5]);
                vals.push(v(scan, seg));
            }
        }
        // Scan 4 touches the wall's end with another segment that runs on past it, where
        // scans 3 and 6 saw the ground (their unsegmented points): one voxel of four shared.
        for k in 0..4 {
            xyz.push([9.8 + 0.5 * k as f64, 0.0, 1.0]);
            vals.push(v(4, 9));
        }
        for scan in [3, 6] {
            for k in 1..4 {
                xyz.push([9.8 + 0.5 * k as f64, 0.0, 1.1]);
                vals.push(v(scan, 0));
            }
        }
        // (The stray is one scan's segment where others looked: see the next test.)
        let p = TieParams {
            confirm: false,
            ..ties_only()
        };
        let (labels, st) = tie_all(&xyz, &vals, None, &p);
        assert_eq!(st.scans, 3);
        assert_eq!(st.scan_segments, 6);
        let wall = labels[0];
        assert!(labels[..120].iter().all(|&l| l == wall), "{labels:?}");
        let pole = labels[120];
        assert!(pole != wall && labels[120..140].iter().all(|&l| l == pole));
        assert!(labels[140] != wall && labels[140] != pole);
        assert!(labels[140..144].iter().all(|&l| l == labels[140]));
        assert_eq!(st.world_segments, 3);
        assert_eq!(wall, 1, "numbered by first point");
    }

    /// A segment found by one scan only, in voxels the next scan observed, is left
    /// unsegmented; one in voxels no other scan observed stays, and so does a segment that
    /// ties across scans.
    #[test]
    fn a_segment_needs_a_second_scan_where_one_looked() {
        let (mut xyz, mut vals) = (Vec::new(), Vec::new());
        for (scan, seg) in [(1u64, 1u64), (2, 1)] {
            for k in 0..20 {
                xyz.push([k as f64 * 0.2, 0.0, 0.0]);
                vals.push(v(scan, seg));
            }
        }
        // Scan 1 only: a piece at x = 10 that scan 2 saw unsegmented, one at x = 20 it missed.
        for k in 0..12 {
            xyz.push([10.0 + k as f64 * 0.05, 0.0, 0.0]);
            vals.push(v(1, 2));
            xyz.push([20.0 + k as f64 * 0.05, 0.0, 0.0]);
            vals.push(v(1, 3));
        }
        xyz.push([10.1, 0.0, 0.0]);
        vals.push(v(2, 0));
        let run = |confirm| {
            let p = TieParams {
                confirm,
                ..ties_only()
            };
            tie_all(&xyz, &vals, None, &p)
        };
        let at = |l: &[u32], value: u64| l[vals.iter().position(|&x| x == value).unwrap()];
        let (l, st) = run(true);
        assert_eq!(st.unconfirmed, 1);
        assert_ne!(at(&l, v(1, 1)), 0);
        assert_eq!(at(&l, v(1, 1)), at(&l, v(2, 1)));
        assert_eq!(at(&l, v(1, 2)), 0, "found by one scan where another looked");
        assert_ne!(at(&l, v(1, 3)), 0, "no other scan looked there");
        assert_eq!(st.world_segments, 2);
        let (l, st) = run(false);
        assert_ne!(at(&l, v(1, 2)), 0);
        assert_eq!((st.unconfirmed, st.world_segments), (0, 3));
    }

    /// Points without a value, not observed, or not members get no segment; segment 0 of a
    /// scan is no segment but still shows what the scan saw.
    #[test]
    fn non_members_and_unsegmented_points_stay_zero() {
        let xyz = vec![[0.0, 0.0, 0.0]; 4];
        let vals = vec![0, v(1, 0), v(1, 3), v(1, 3)];
        let observe = vec![true, true, true, false];
        let member = vec![true, true, false, true];
        let (labels, st) = tie(
            &xyz,
            &vals,
            &observe,
            &member,
            None,
            [0.0; 3],
            &TieParams::default(),
        );
        assert_eq!(labels, vec![0, 0, 0, 0]);
        assert_eq!(st.world_segments, 0);
        assert_eq!(st.scans, 1);
        let (labels, _) = tie(&[], &[], &[], &[], None, [0.0; 3], &TieParams::default());
        assert!(labels.is_empty());
    }

    /// Scan 2 sees the 20 voxels of scan 1's segment, but only 8 of them as its segment 4
    /// (the rest unsegmented). One-to-one ("larger"): 8 of 20 is no majority, apart; a lower
    /// fraction joins them. "smaller": segment 4 lies wholly inside, joined.
    #[test]
    fn majority_fraction_and_basis_decide() {
        let mut xyz = Vec::new();
        let mut vals = Vec::new();
        for k in 0..20 {
            xyz.push([k as f64, 0.0, 0.0]);
            vals.push(v(1, 1));
        }
        for k in 0..20 {
            xyz.push([k as f64, 0.0, 0.0]);
            vals.push(v(2, if k < 8 { 4 } else { 0 }));
        }
        let with = |basis, majority_fraction| TieParams {
            basis,
            majority_fraction,
            confirm: false,
            ..ties_only()
        };
        let (l, st) = tie_all(&xyz, &vals, None, &with(TieBasis::Larger, 0.5));
        assert_eq!(st.ties, 0);
        assert_ne!(l[0], l[20]);
        let (l, st) = tie_all(&xyz, &vals, None, &with(TieBasis::Larger, 0.3));
        assert_eq!(st.ties, 1);
        assert_eq!(l[0], l[20]);
        let (l, st) = tie_all(&xyz, &vals, None, &with(TieBasis::Smaller, 0.9));
        assert_eq!(st.ties, 1);
        assert_eq!(l[0], l[20]);
    }

    /// A window's glass 0.1 m behind its façade shares the façade's voxels: without the plane
    /// check it joins the next scan's façade; with it, it stays apart while the façade's pieces
    /// still tie. A piece inside a non-planar segment (a car) is not checked and joins.
    #[test]
    fn a_piece_off_a_planar_segment_does_not_join_it() {
        let mut xyz = Vec::new();
        let mut vals = Vec::new();
        let window = |x: f64, z: f64| (1.0..2.5).contains(&x) && (1.0..2.5).contains(&z);
        for (scan, seg) in [(1u64, 1u64), (2, 2)] {
            for ix in 0..50 {
                for iz in 0..30 {
                    let (x, z) = (ix as f64 * 0.1 + 0.01, iz as f64 * 0.1 + 0.01);
                    if scan == 1 && window(x, z) {
                        xyz.push([x, 0.1, z]);
                        vals.push(v(1, 3));
                    } else {
                        xyz.push([x, 0.0, z]);
                        vals.push(v(scan, seg));
                    }
                }
            }
        }
        // A car: a sphere of radius 1 at (10, 0, 1) in scan 2 (segment 5); in scan 1 a piece
        // of its surface (segment 6).
        for i in 0..400 {
            let (u, w) = (i as f64 * 0.7, (i as f64 * 0.37).sin());
            let r = (1.0 - w * w).sqrt();
            let q = [10.0 + r * u.cos(), r * u.sin(), 1.0 + w];
            xyz.push(q);
            vals.push(v(2, 5));
            if q[0] < 10.0 {
                xyz.push([q[0] + 0.01, q[1], q[2]]);
                vals.push(v(1, 6));
            }
        }
        let run = |plane_tolerance_m| {
            let p = TieParams {
                plane_tolerance_m,
                ..ties_only()
            };
            tie_all(&xyz, &vals, None, &p).0
        };
        let at = |l: &[u32], value: u64| l[vals.iter().position(|&x| x == value).unwrap()];
        let loose = run(0.0);
        assert_eq!(
            at(&loose, v(1, 3)),
            at(&loose, v(2, 2)),
            "window joins the facade"
        );
        let strict = run(0.05);
        assert_ne!(
            at(&strict, v(1, 3)),
            at(&strict, v(2, 2)),
            "window stays apart"
        );
        assert_eq!(
            at(&strict, v(1, 1)),
            at(&strict, v(2, 2)),
            "facade pieces tie"
        );
        assert_eq!(
            at(&strict, v(1, 6)),
            at(&strict, v(2, 5)),
            "car piece joins the car"
        );
    }

    /// Points of a wall in the plane y = 0 over `x0..x1`, 0..3 m high, every 0.1 m.
    fn wall(x0: f64, x1: f64, value: u64, xyz: &mut Vec<[f64; 3]>, vals: &mut Vec<u64>) {
        let mut x = x0 + 0.01;
        while x < x1 {
            for iz in 0..30 {
                xyz.push([x, 0.0, iz as f64 * 0.1 + 0.01]);
                vals.push(value);
            }
            x += 0.1;
        }
    }

    /// Two buildings' façades in one plane, meeting at x = 5: their pieces share voxels there
    /// but differ in colour, so only the colour check keeps them apart. The first façade is
    /// split where a shadow falls, at x = 2 in scan 1 and x = 3 in scan 2: the pieces of
    /// consecutive scans overlap too little for a majority but tie as one plane and colour.
    /// Scan 1 splits the second façade too, at x = 8.6, beyond what scan 2 saw: its pieces
    /// tie with each other.
    #[test]
    fn coplanar_pieces_tie_by_colour_and_touch() {
        let (mut xyz, mut vals) = (Vec::new(), Vec::new());
        wall(0.0, 2.0, v(1, 1), &mut xyz, &mut vals);
        wall(2.0, 5.0, v(1, 2), &mut xyz, &mut vals);
        wall(0.0, 3.0, v(2, 1), &mut xyz, &mut vals);
        wall(3.0, 5.0, v(2, 2), &mut xyz, &mut vals);
        let first = xyz.len();
        wall(5.0, 8.6, v(1, 3), &mut xyz, &mut vals);
        wall(8.6, 10.0, v(1, 5), &mut xyz, &mut vals);
        wall(4.8, 7.0, v(2, 3), &mut xyz, &mut vals);
        let lab: Vec<[f32; 3]> = (0..xyz.len())
            .map(|i| {
                if i < first {
                    [80.0, 5.0, 20.0]
                } else {
                    [60.0, 10.0, 40.0]
                }
            })
            .collect();
        let run = |colour_tolerance, lab| {
            let p = TieParams {
                colour_tolerance,
                min_shared_voxels: 1,
                ..ties_only()
            };
            tie_all(&xyz, &vals, lab, &p).0
        };
        let at = |l: &[u32], value: u64| l[vals.iter().position(|&x| x == value).unwrap()];
        let l = run(10.0, Some(&lab[..]));
        let one = at(&l, v(1, 1));
        for piece in [v(1, 2), v(2, 1), v(2, 2)] {
            assert_eq!(at(&l, piece), one, "{piece:x}: one facade");
        }
        assert_ne!(at(&l, v(2, 3)), one, "the neighbour's facade stays apart");
        assert_eq!(at(&l, v(1, 3)), at(&l, v(2, 3)));
        // Scan 1's piece beyond what scan 2 saw touches only scan 1's other piece.
        assert_eq!(at(&l, v(1, 5)), at(&l, v(1, 3)), "pieces of one scan");
        // Without colour (or with the check off) the shared voxels at x = 5 join them.
        for l in [run(10.0, None), run(0.0, Some(&lab[..]))] {
            assert_eq!(at(&l, v(2, 3)), at(&l, v(1, 1)));
        }
    }
}
