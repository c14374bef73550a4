//! Refinement of the world segments on the drive's points together.
//!
//! A scan sees a surface with a few returns: on 16 or 32 rings a window 10 cm behind its
//! façade, framed in the façade's colour, gets 2–15 returns per scan, too few for the range,
//! normal or colour cue to tell it from the wall, so the scan's façade segment holds it and so
//! does the world segment the ties make; returns below a scan's `min_points` stay unsegmented.
//! The drive's points of the same place together are dense enough for plane geometry. After
//! the ties, in each tile:
//! 1. **split**: a world segment with a dominant plane ([`dominant_plane`]) keeps the points
//!    within `plane_tolerance_m` of it; the others become pieces of their own by voxel
//!    connectivity. A segment without one keeps its largest part connected through the
//!    ties' voxels (its other parts become segments) and gives the stem that part stands on
//!    ([`stem_of`]) a segment of its own;
//! 2. **attach**: an unsegmented point takes the segment in its own or a neighbouring voxel
//!    whose plane lies nearest to it, within the tolerance — and, pass by pass, a wide plane
//!    of its colour reached through points attached before it; the points still left become
//!    pieces by voxel connectivity, split off their dominant planes as in step 1;
//! 3. **join** ([`join_touching`]): touching segments that are one surface (one lies on the
//!    other's plane) or one object (a segment enclosed by a larger one without a plane: a
//!    car's glass and its body) are joined.
//!
//! Everything depends only on the tile's points (RANSAC draws from a generator seeded by the
//! points; maps are read in a fixed order), not on threads. The tile stitching then joins the
//! refined segments across tiles as for region growing.

use super::meanshift::UnionFind;
use crate::segment::features::{Moments, Plane};
use std::collections::HashMap;

/// No node / no segment.
const NONE: u32 = u32::MAX;

/// Least points of a new piece; smaller ones stay unsegmented.
const MIN_PIECE_POINTS: usize = 10;

/// The refinement's parameters (from `[segment.tie]`, see [`super::ties::TieParams`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct RefineParams {
    /// Voxel edge, metres (> 0).
    pub voxel_m: f64,
    /// Plane tolerance, metres (> 0).
    pub plane_tolerance_m: f64,
    /// Least share of a segment's points on its dominant plane (0: no split).
    pub dominant_fraction: f64,
    /// Colour tolerance of coplanar joins, ΔE*ab (0: none).
    pub colour_tolerance: f64,
    /// Horizontal radius of a stem about its axis, metres (0: no stems split off).
    pub stem_radius_m: f64,
    /// Least height of a stem, and how far the rest of its segment must rise above it, metres.
    pub stem_min_height_m: f64,
    /// Segments without a dominant plane are split into their parts connected through
    /// voxels of this edge, metres (0: no split).
    pub apart_voxel_m: f64,
    /// A dominant plane's points in two colours ([`colour_split`]) are split by colour.
    pub split_colours: bool,
    /// Step 2 repeats while points attach (a plane reached through attached points).
    pub attach_grows: bool,
}

/// What [`refine`] did.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Refined {
    /// Segments after the refinement (labels 1..=segments).
    pub segments: u32,
    /// Pieces split off dominant planes.
    pub split_off: usize,
    /// Parts of segments without a dominant plane that lay apart from the rest.
    pub apart: usize,
    /// Stems split off the objects they carry.
    pub stems: usize,
    /// Unsegmented points attached to a plane.
    pub attached: usize,
    /// Pieces formed by the points left over.
    pub leftover_segments: usize,
}

/// Refines the world segments `labels` (0 = none, 1..=`segments`) of a tile; `wanted` are the
/// points that should have a segment (the segment stage's members, finite). Labels are
/// renumbered 1.. by first point.
pub(super) fn refine(
    xyz: &[[f64; 3]],
    labels: &mut [u32],
    segments: u32,
    wanted: &[bool],
    lab: Option<&[[f32; 3]]>,
    origin: [f64; 3],
    p: &RefineParams,
) -> Refined {
    let grid = Grid {
        origin,
        inv: 1.0 / p.voxel_m,
    };
    let mut next = segments;
    let mut out = Refined::default();
    let split = if p.dominant_fraction > 0.0 || p.stem_radius_m > 0.0 || p.apart_voxel_m > 0.0 {
        split_segments(xyz, labels, segments, lab, &grid, p)
    } else {
        Split::default()
    };
    // Parts that lay apart are segments in their own right (their colour is their own).
    out.apart = label_pieces(split.apart, labels, &mut next);
    // Pieces are labelled above this; their colour is not their own evidence (see
    // `join_touching`).
    let first_piece = next;
    out.split_off = label_pieces(split.pieces, labels, &mut next);
    out.stems = label_pieces(split.stems, labels, &mut next);
    let left: Vec<u32> = (0..labels.len() as u32)
        .filter(|&i| wanted[i as usize] && labels[i as usize] == 0)
        .collect();
    let (attached, rest) = attach_to_planes(xyz, labels, next, &left, lab, &grid, p);
    out.attached = attached;
    // The points left over form pieces of their own, each split off its dominant plane as
    // the world segments were in step 1: a band of a façade that no scan segmented holds the
    // windows 10 cm behind it, and as one piece it lay on the façade's plane and joined it.
    let mut leftover = Vec::new();
    for part in grid.components(xyz, &rest) {
        let plane = if part.len() >= MIN_PIECE_POINTS && p.dominant_fraction > 0.0 {
            dominant_plane(
                xyz,
                &part,
                grid.origin,
                p.plane_tolerance_m,
                p.dominant_fraction,
            )
        } else {
            None
        };
        match plane {
            Some(plane) => {
                let (on, off): (Vec<u32>, Vec<u32>) = part
                    .iter()
                    .partition(|&&i| plane.dist(&xyz[i as usize]) <= p.plane_tolerance_m);
                leftover.push(on);
                leftover.extend(grid.components(xyz, &off));
            }
            _ => leftover.push(part),
        }
    }
    out.leftover_segments = label_pieces(leftover, labels, &mut next);
    out.segments = join_touching(xyz, labels, lab, next, first_piece, &grid, p);
    out
}

/// Gives each piece of at least [`MIN_PIECE_POINTS`] points the next label (after `next`),
/// the points of smaller ones label 0; returns how many pieces were labelled.
fn label_pieces(
    pieces: impl IntoIterator<Item = Vec<u32>>,
    labels: &mut [u32],
    next: &mut u32,
) -> usize {
    let mut labelled = 0;
    for piece in pieces {
        let l = if piece.len() >= MIN_PIECE_POINTS {
            *next += 1;
            labelled += 1;
            *next
        } else {
            0
        };
        for i in piece {
            labels[i as usize] = l;
        }
    }
    labelled
}

/// A voxel grid of one edge over a tile.
struct Grid {
    origin: [f64; 3],
    inv: f64,
}

impl Grid {
    fn key(&self, q: &[f64; 3]) -> [i64; 3] {
        std::array::from_fn(|k| ((q[k] - self.origin[k]) * self.inv).floor() as i64)
    }

    /// The 27 voxels around `c` (itself included).
    fn around(c: [i64; 3]) -> impl Iterator<Item = [i64; 3]> {
        (0..27i64).map(move |d| [c[0] + d / 9 - 1, c[1] + d / 3 % 3 - 1, c[2] + d % 3 - 1])
    }

    /// The labels present in each voxel (each once, in order of first point).
    fn labels(&self, xyz: &[[f64; 3]], labels: &[u32]) -> HashMap<[i64; 3], Vec<u32>> {
        let mut voxel: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (q, &l) in xyz.iter().zip(labels) {
            if l != 0 {
                let v = voxel.entry(self.key(q)).or_default();
                if !v.contains(&l) {
                    v.push(l);
                }
            }
        }
        voxel
    }

    /// The points `idx` grouped by connectivity: two points connect when their voxels touch
    /// (26-neighbours). Groups in order of their first point, points in input order.
    fn components(&self, xyz: &[[f64; 3]], idx: &[u32]) -> Vec<Vec<u32>> {
        let mut cell_of: HashMap<[i64; 3], u32> = HashMap::new();
        let cell: Vec<u32> = idx
            .iter()
            .map(|&i| {
                let n = cell_of.len() as u32;
                *cell_of.entry(self.key(&xyz[i as usize])).or_insert(n)
            })
            .collect();
        let mut uf = UnionFind::new(cell_of.len());
        for (k, &c) in &cell_of {
            for q in Self::around(*k) {
                if let Some(&c2) = cell_of.get(&q) {
                    uf.union(c as usize, c2 as usize);
                }
            }
        }
        let mut group_of: HashMap<usize, usize> = HashMap::new();
        let mut groups: Vec<Vec<u32>> = Vec::new();
        for (&i, &c) in idx.iter().zip(&cell) {
            let g = *group_of.entry(uf.find(c as usize)).or_insert_with(|| {
                groups.push(Vec::new());
                groups.len() - 1
            });
            groups[g].push(i);
        }
        groups
    }
}

/// Node per point for labels 1..: label − 1, [`NONE`] for 0.
fn label_nodes(labels: &[u32]) -> Vec<u32> {
    labels
        .iter()
        .map(|&l| if l == 0 { NONE } else { l - 1 })
        .collect()
}

/// What step 1 takes out of the segments; the caller labels each group.
#[derive(Default)]
struct Split {
    /// Parts of segments without a dominant plane that lie apart from the segment's largest.
    apart: Vec<Vec<u32>>,
    /// Points off a dominant plane, by voxel connectivity.
    pieces: Vec<Vec<u32>>,
    /// Stems ([`stem_of`]).
    stems: Vec<Vec<u32>>,
}

/// Step 1: for every segment with a dominant plane, the pieces its points off that plane form
/// (voxel connectivity); every other segment keeps its largest part connected through voxels
/// of `apart_voxel_m`, and gives the stem that part stands on ([`stem_of`]).
fn split_segments(
    xyz: &[[f64; 3]],
    labels: &[u32],
    segments: u32,
    lab: Option<&[[f32; 3]]>,
    grid: &Grid,
    p: &RefineParams,
) -> Split {
    let tol = p.plane_tolerance_m;
    let members = Members::new(&label_nodes(labels), segments as usize);
    let mut out = Split::default();
    for seg in 0..segments as usize {
        let idx = members.of(seg);
        match dominant_plane(xyz, idx, grid.origin, tol, p.dominant_fraction) {
            Some(plane) => {
                let off: Vec<u32> = idx
                    .iter()
                    .copied()
                    .filter(|&i| plane.dist(&xyz[i as usize]) > tol)
                    .collect();
                out.pieces.extend(grid.components(xyz, &off));
                if let (Some(lab), true) = (lab, p.split_colours && p.colour_tolerance > 0.0) {
                    let mut on: Vec<u32> = idx
                        .iter()
                        .copied()
                        .filter(|&i| plane.dist(&xyz[i as usize]) <= tol)
                        .collect();
                    // Two buildings' façades in one plane, joined where a scan's segment
                    // straddled their border (its mean colour lies near both): each colour
                    // that holds a region of its own leaves. At most three colours leave.
                    for _ in 0..3 {
                        let Some((keep, other)) = colour_split(xyz, &on, lab, grid, p) else {
                            break;
                        };
                        out.apart.extend(
                            grid.components(xyz, &other)
                                .into_iter()
                                .filter(|part| part.len() >= MIN_PIECE_POINTS),
                        );
                        on = keep;
                    }
                }
            }
            None => {
                // An object is one connected body. A scan's image joins returns that are no
                // neighbours in space — across a ring step, where the angle test lets a range
                // jump pass on a sparse sensor (16 rings: a car's roof and a window 3.8 m
                // behind it, one grey in the colour cue), or through points that are no
                // members here (a parked car, the kerb, the footpath and the façade) — and
                // the ties carry such joins into the world segment: its parts then lie apart.
                // The largest part keeps the segment, other parts of MIN_PIECE_POINTS or more
                // become segments, smaller ones stay (a few stray returns). Parts connect
                // through voxels of the ties' edge, the scale at which consecutive scans'
                // samples of one surface meet: 0.25 m voxels broke windows seen by 16 rings.
                let mut parts = if p.apart_voxel_m > 0.0 {
                    let apart = Grid {
                        origin: grid.origin,
                        inv: 1.0 / p.apart_voxel_m,
                    };
                    apart.components(xyz, idx)
                } else {
                    vec![idx.to_vec()]
                };
                let main = (0..parts.len())
                    .max_by_key(|&k| (parts[k].len(), std::cmp::Reverse(k)))
                    .unwrap_or(0);
                let body = std::mem::take(&mut parts[main]);
                out.apart.extend(
                    parts
                        .into_iter()
                        .filter(|part| part.len() >= MIN_PIECE_POINTS),
                );
                out.stems.extend(stem_of(xyz, &body, p, 1.0 / grid.inv));
            }
        }
    }
    out
}

/// The points `on` (of one plane) split by colour, when they hold two colours more than
/// `colour_tolerance` apart (ΔE*ab) that each fill regions of their own: two façades in one
/// plane. The colours are found by 2-means in CIELab, started from the split across the
/// colours' principal axis; each voxel's points then go together to the colour most of them
/// have, and at least half of the points must lie in voxels that are ≥ 80 % one colour — a
/// brick wall's bricks and mortar mix in every voxel and stay one surface. Returns (the larger
/// colour's points, the other's), None when the points are one colour.
fn colour_split(
    xyz: &[[f64; 3]],
    on: &[u32],
    lab: &[[f32; 3]],
    grid: &Grid,
    p: &RefineParams,
) -> Option<(Vec<u32>, Vec<u32>)> {
    if on.len() < 2 * MIN_PIECE_POINTS {
        return None;
    }
    let col = |i: u32| lab[i as usize].map(f64::from);
    let n = on.len() as f64;
    let mut mean = [0.0; 3];
    for &i in on {
        let c = col(i);
        (0..3).for_each(|k| mean[k] += c[k] / n);
    }
    let mut cov = [[0.0; 3]; 3];
    for &i in on {
        let c = col(i);
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += (c[a] - mean[a]) * (c[b] - mean[b]) / n;
            }
        }
    }
    // Principal axis by power iteration, from the coordinate axis of largest variance.
    let mut axis = [0.0; 3];
    let big = (0..3)
        .max_by(|&a, &b| cov[a][a].total_cmp(&cov[b][b]))
        .unwrap_or(0);
    axis[big] = 1.0;
    for _ in 0..30 {
        let v: [f64; 3] = std::array::from_fn(|a| (0..3).map(|b| cov[a][b] * axis[b]).sum());
        let len = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if len <= 1e-12 {
            return None;
        }
        axis = v.map(|x| x / len);
    }
    let d2 = |c: [f64; 3], m: [f64; 3]| (0..3).map(|k| (c[k] - m[k]).powi(2)).sum::<f64>();
    let mut side: Vec<bool> = on
        .iter()
        .map(|&i| {
            let c = col(i);
            (0..3).map(|k| (c[k] - mean[k]) * axis[k]).sum::<f64>() > 0.0
        })
        .collect();
    let mut means = [[0.0; 3]; 2];
    for _ in 0..10 {
        let mut sum = [[0.0; 3]; 2];
        let mut cnt = [0usize; 2];
        for (&i, &s) in on.iter().zip(&side) {
            let c = col(i);
            (0..3).for_each(|k| sum[s as usize][k] += c[k]);
            cnt[s as usize] += 1;
        }
        if cnt.contains(&0) {
            return None;
        }
        means = std::array::from_fn(|g| sum[g].map(|v| v / cnt[g] as f64));
        let mut moved = false;
        for (&i, s) in on.iter().zip(side.iter_mut()) {
            let c = col(i);
            let t = d2(c, means[1]) < d2(c, means[0]);
            moved |= t != *s;
            *s = t;
        }
        if !moved {
            break;
        }
    }
    if d2(means[0], means[1]).sqrt() <= p.colour_tolerance {
        return None;
    }
    // Per voxel: points of each colour.
    let mut voxel: HashMap<[i64; 3], [usize; 2]> = HashMap::new();
    for (&i, &s) in on.iter().zip(&side) {
        voxel.entry(grid.key(&xyz[i as usize])).or_default()[s as usize] += 1;
    }
    let pure: usize = voxel
        .values()
        .filter(|c| 5 * c[0].max(c[1]) >= 4 * (c[0] + c[1]))
        .map(|c| c[0] + c[1])
        .sum();
    if 2 * pure < on.len() {
        return None;
    }
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for &i in on {
        let c = voxel[&grid.key(&xyz[i as usize])];
        if c[1] > c[0] {
            b.push(i);
        } else {
            a.push(i);
        }
    }
    if a.len() < b.len() {
        std::mem::swap(&mut a, &mut b);
    }
    if b.len() < MIN_PIECE_POINTS {
        return None;
    }
    Some((a, b))
}

/// The stem a segment stands on, when it carries something wider that rises above it: a tree's
/// trunk under its crown (a scan's range and colour cues join them where the trunk enters the
/// crown, and every scan's segment ties them again). The stem's axis is vertical through the
/// mean of the segment's lowest `stem_min_height_m / 2`, where at least 90 % of the points
/// lie within `stem_radius_m` of it; the stem is the points within that radius, upwards from
/// the lowest without a vertical gap over `gap` (one voxel), at least `stem_min_height_m`
/// tall. The rest must hold [`MIN_PIECE_POINTS`] and reach `stem_min_height_m` above the
/// stem's top: a pole's arm or a sign at its top stays with the pole, a pole or a person
/// (all stem) stays whole, and a car or a bush has no narrow base.
fn stem_of(xyz: &[[f64; 3]], idx: &[u32], p: &RefineParams, gap: f64) -> Option<Vec<u32>> {
    let (r, h) = (p.stem_radius_m, p.stem_min_height_m);
    if r <= 0.0 || idx.len() < 2 * MIN_PIECE_POINTS {
        return None;
    }
    let z = |i: u32| xyz[i as usize][2];
    let z_min = idx.iter().map(|&i| z(i)).fold(f64::INFINITY, f64::min);
    let base: Vec<u32> = idx
        .iter()
        .copied()
        .filter(|&i| z(i) <= z_min + 0.5 * h)
        .collect();
    let mut axis = [0.0; 2];
    for &i in &base {
        axis[0] += xyz[i as usize][0] / base.len() as f64;
        axis[1] += xyz[i as usize][1] / base.len() as f64;
    }
    let near = |i: u32| {
        let q = xyz[i as usize];
        (q[0] - axis[0]).powi(2) + (q[1] - axis[1]).powi(2) <= r * r
    };
    if 10 * base.iter().filter(|&&i| !near(i)).count() > base.len() {
        return None;
    }
    let mut column: Vec<(f64, u32)> = idx
        .iter()
        .filter(|&&i| near(i))
        .map(|&i| (z(i), i))
        .collect();
    column.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut top = z_min;
    let mut stem: Vec<u32> = Vec::new();
    for &(zi, i) in &column {
        if zi - top > gap {
            break;
        }
        top = top.max(zi);
        stem.push(i);
    }
    // The segment's top is the rest's unless the stem reaches it (then nothing rises above).
    let seg_top = idx.iter().map(|&i| z(i)).fold(f64::NEG_INFINITY, f64::max);
    if top - z_min < h || idx.len() - stem.len() < MIN_PIECE_POINTS || seg_top < top + h {
        return None;
    }
    stem.sort_unstable();
    Some(stem)
}

/// Step 2: each point of `left` takes the segment (with a plane, [`SegmentShape`]) in its own
/// or a neighbouring voxel whose plane lies nearest, within `plane_tolerance_m`; with
/// `attach_grows`, repeated while points attach, through wide planes of the point's colour
/// only after the first pass. Returns how many did, and the others.
fn attach_to_planes(
    xyz: &[[f64; 3]],
    labels: &mut [u32],
    segments: u32,
    left: &[u32],
    lab: Option<&[[f32; 3]]>,
    grid: &Grid,
    p: &RefineParams,
) -> (usize, Vec<u32>) {
    let tol = p.plane_tolerance_m;
    let members = Members::new(&label_nodes(labels), segments as usize);
    let mut voxel = grid.labels(xyz, labels);
    // Per segment: its plane, whether wide, its mean colour.
    type Reach = (Option<Plane>, bool, Option<[f64; 3]>);
    let mut planes: HashMap<u32, Reach> = HashMap::new();
    let colour_tol = if p.colour_tolerance > 0.0 {
        p.colour_tolerance
    } else {
        f64::INFINITY
    };
    let mut left = left.to_vec();
    let mut attached = 0;
    // Passes until none attaches: a point attached in one pass lets its neighbours reach the
    // segment's plane (fixed from the segment as it was) in the next, so a band of a façade no
    // scan segmented joins its façade across the band, and what lies off the plane (windows
    // 10 cm behind) is left over. Only wide planes grow so (façades, not a crown's flat-looking
    // patches, through which a crown's points had reached other segments), and only through
    // points of their colour (not into the neighbouring building's façade in the same plane).
    // After the first pass, only points next to a voxel that gained a label are searched again
    // (the others would find what they found before, under the first pass's wider rule).
    let mut changed: Option<std::collections::HashSet<[i64; 3]>> = None;
    for pass in 0.. {
        let mut rest = Vec::new();
        let mut take = Vec::new();
        for &i in &left {
            let q = &xyz[i as usize];
            if changed.as_ref().is_some_and(|c| !c.contains(&grid.key(q))) {
                rest.push(i);
                continue;
            }
            let mut best: Option<(f64, u32)> = None;
            for v in Grid::around(grid.key(q)) {
                for &o in voxel.get(&v).map_or(&[][..], |v| v.as_slice()) {
                    let (plane, wide, colour) = *planes.entry(o).or_insert_with(|| {
                        let s =
                            SegmentShape::new(xyz, members.of(o as usize - 1), lab, grid.origin, p);
                        (s.plane, s.wide, s.colour)
                    });
                    let grows = || {
                        let near = match (lab, colour) {
                            (Some(lab), Some(c)) => {
                                let d2: f64 = (0..3)
                                    .map(|k| (lab[i as usize][k] as f64 - c[k]).powi(2))
                                    .sum();
                                d2.sqrt() <= colour_tol
                            }
                            _ => true,
                        };
                        wide && near
                    };
                    let Some(pl) = plane.filter(|_| pass == 0 || grows()) else {
                        continue;
                    };
                    let d = pl.dist(q);
                    if d <= tol && best.is_none_or(|b| (d, o) < b) {
                        best = Some((d, o));
                    }
                }
            }
            match best {
                Some((_, o)) => take.push((i, o)),
                None => rest.push(i),
            }
        }
        // Assigned after the search, so a point's choice does not depend on earlier points.
        for &(i, o) in &take {
            labels[i as usize] = o;
            let v = voxel.entry(grid.key(&xyz[i as usize])).or_default();
            if !v.contains(&o) {
                v.push(o);
            }
        }
        attached += take.len();
        left = rest;
        if take.is_empty() || !p.attach_grows {
            break;
        }
        let mut c = std::collections::HashSet::new();
        for &(i, _) in &take {
            c.extend(Grid::around(grid.key(&xyz[i as usize])));
        }
        changed = Some(c);
    }
    (attached, left)
}

/// Step 3: joins segments that touch (points in the same or neighbouring voxels) and are one
/// surface or one object, each to the touching segment with the most such voxels:
/// - a segment lying on another's plane ([`SegmentShape::plane`]; RMS distance within
///   `plane_tolerance_m`) joins it, with its colour (`colour_tolerance`) unless it is a
///   piece (labels above `first_piece`: its colour is what had put it with the plane it was
///   split from, or it had none; a window's frame and its glass are one surface in two
///   colours) — two buildings' façades in one plane stay apart by colour;
/// - else a segment that is not a wide plane joins a larger segment without a plane that
///   encloses it — most of its voxels touch that segment (a car's glass, mirror or wheel,
///   found apart by a few scans, joins the car; a car parked against another does not).
///
/// Decisions use the segments as they were before any join, so they do not depend on order.
/// Labels are renumbered 1.. by first point; returns the number of segments.
fn join_touching(
    xyz: &[[f64; 3]],
    labels: &mut [u32],
    lab: Option<&[[f32; 3]]>,
    segments: u32,
    first_piece: u32,
    grid: &Grid,
    p: &RefineParams,
) -> u32 {
    let tol = p.plane_tolerance_m;
    let members = Members::new(&label_nodes(labels), segments as usize);
    let voxel = grid.labels(xyz, labels);
    let shapes: Vec<SegmentShape> = (0..segments as usize)
        .map(|s| SegmentShape::new(xyz, members.of(s), lab, grid.origin, p))
        .collect();
    let shape = |l: u32| &shapes[l as usize - 1];
    let colour_tol = if p.colour_tolerance > 0.0 {
        p.colour_tolerance
    } else {
        f64::INFINITY
    };
    let mut uf = UnionFind::new(segments as usize + 1);
    for l in 1..=segments {
        let s = shape(l);
        let mut cells: Vec<[i64; 3]> = members
            .of(l as usize - 1)
            .iter()
            .map(|&i| grid.key(&xyz[i as usize]))
            .collect();
        cells.sort_unstable();
        cells.dedup();
        // Per segment, how many of this one's voxels touch it (each voxel counted once).
        let mut touch: HashMap<u32, usize> = HashMap::new();
        let mut near: Vec<u32> = Vec::new();
        for c in &cells {
            near.clear();
            for v in Grid::around(*c) {
                near.extend(voxel.get(&v).map_or(&[][..], |v| v.as_slice()));
            }
            near.sort_unstable();
            near.dedup();
            for &o in near.iter().filter(|&&o| o != l) {
                *touch.entry(o).or_default() += 1;
            }
        }
        // Most touching voxels first, then the smaller label: a fixed order.
        let mut order: Vec<(u32, usize)> = touch.into_iter().collect();
        order.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let piece = l > first_piece;
        let lies_on = |o: u32, colour: bool| {
            let t = shape(o);
            t.plane.is_some_and(|pl| {
                s.moments
                    .mean_sq_distance(&pl)
                    .is_some_and(|d2| d2.sqrt() <= tol)
                    && (!colour || s.colour_distance(t) <= colour_tol)
            })
        };
        // A piece takes a plane of its own colour where one touches it, else any: a façade's
        // piece touching its façade and, in the same plane, the neighbouring building's façade
        // in another colour joins its own (joining either chained the two façades).
        let on_plane = order
            .iter()
            .find(|&&(o, _)| lies_on(o, true))
            .or_else(|| order.iter().find(|&&(o, _)| piece && lies_on(o, false)));
        // A stem is enclosed only by a stem: a trunk's piece joins the trunk, the trunk does
        // not join the crown it touches with half its voxels.
        let enclosed_by = || {
            if s.wide {
                return None;
            }
            order.iter().find(|&&(o, k)| {
                let t = shape(o);
                // (A trunk seen from one side may pass for flat: its half-cylinder is within
                // the plane tolerance; it is still the stem its pieces belong to.)
                let encloses = if s.upright {
                    t.upright
                } else {
                    t.plane.is_none()
                };
                encloses && t.moments.n > s.moments.n && 2 * k > cells.len()
            })
        };
        if let Some(&(o, _)) = on_plane.or_else(enclosed_by) {
            uf.union(l as usize, o as usize);
        }
    }
    let mut renumber: HashMap<usize, u32> = HashMap::new();
    for l in labels.iter_mut().filter(|l| **l != 0) {
        let r = uf.find(*l as usize);
        let n = renumber.len() as u32 + 1;
        *l = *renumber.entry(r).or_insert(n);
    }
    renumber.len() as u32
}

/// A segment's shape for the attach and join steps.
struct SegmentShape {
    moments: Moments,
    /// Its plane: least-squares if flat with a defined plane (spread ≥ 2 × the tolerance: a
    /// window ~1 m wide is, a pole is not), else dominant.
    plane: Option<Plane>,
    /// A wide plane (the ties' planar test: façades, not windows or car parts).
    wide: bool,
    /// An upright stem ([`upright`]: a trunk, a pole).
    upright: bool,
    colour: Option<[f64; 3]>,
}

impl SegmentShape {
    fn new(
        xyz: &[[f64; 3]],
        idx: &[u32],
        lab: Option<&[[f32; 3]]>,
        origin: [f64; 3],
        p: &RefineParams,
    ) -> Self {
        let tol = p.plane_tolerance_m;
        let (moments, colour) = sums(xyz, idx, lab, origin);
        let wide = flat_and_wide(&moments, tol).is_some();
        let plane = flat_and(&moments, tol, 2.0 * tol)
            .or_else(|| dominant_plane(xyz, idx, origin, tol, p.dominant_fraction));
        SegmentShape {
            upright: upright(xyz, idx, origin, p),
            moments,
            plane,
            wide,
            colour,
        }
    }

    /// ΔE*ab between the mean colours; 0 without colour.
    fn colour_distance(&self, o: &SegmentShape) -> f64 {
        match (self.colour, o.colour) {
            (Some(x), Some(y)) => (0..3).map(|c| (x[c] - y[c]).powi(2)).sum::<f64>().sqrt(),
            _ => 0.0,
        }
    }
}

/// Whether the points `idx` form an upright stem: at least 90 % of them within
/// `stem_radius_m` of the vertical through their median x and y, and those round — off their
/// best plane by more than half `plane_tolerance_m` (RMS; a window's glass or a door is as
/// narrow but flat, while a trunk's or pole's visible half-cylinder of radius 0.1–0.15 m
/// leaves 3–5 cm) — and at least `stem_min_height_m` tall (the height of points spread evenly
/// along it, √12 standard deviations). A trunk under its crown touches the crown with about
/// half its voxels, as a car's glass touches the car's body; the trunk is an object of its
/// own, enclosed only by another stem (its own larger piece). Judged on the points near the
/// axis, so a stray return metres away does not decide it.
fn upright(xyz: &[[f64; 3]], idx: &[u32], origin: [f64; 3], p: &RefineParams) -> bool {
    let r = p.stem_radius_m;
    if r <= 0.0 || idx.len() < 3 {
        return false;
    }
    let median = |k: usize| {
        let mut v: Vec<f64> = idx.iter().map(|&i| xyz[i as usize][k]).collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let axis = [median(0), median(1)];
    let mut near = Moments::new(origin);
    for &i in idx {
        let q = &xyz[i as usize];
        if (q[0] - axis[0]).powi(2) + (q[1] - axis[1]).powi(2) <= r * r {
            near.add(q);
        }
    }
    if 10 * near.n < 9 * idx.len() {
        return false;
    }
    let round = near
        .eigen()
        .is_some_and(|(_, l, _)| l[0].sqrt() > 0.5 * p.plane_tolerance_m);
    round
        && near
            .variance(2)
            .is_some_and(|v| (12.0 * v).sqrt() >= p.stem_min_height_m)
}

/// The moments of the points `idx` (about `origin`) and their mean CIELab colour (None
/// without colour): what the ties' surfaces and the refinement's shapes are judged by.
pub(super) fn sums<'a>(
    xyz: &[[f64; 3]],
    idx: impl IntoIterator<Item = &'a u32>,
    lab: Option<&[[f32; 3]]>,
    origin: [f64; 3],
) -> (Moments, Option<[f64; 3]>) {
    let mut m = Moments::new(origin);
    let mut c = [0.0f64; 3];
    for &i in idx {
        m.add(&xyz[i as usize]);
        if let Some(lab) = lab {
            for k in 0..3 {
                c[k] += lab[i as usize][k] as f64;
            }
        }
    }
    let colour = lab.map(|_| c.map(|v| v / m.n.max(1) as f64));
    (m, colour)
}

/// The least-squares plane of `m` when its points are planar: flat (RMS residual λ0 ≤ `tol`)
/// and wide along both in-plane axes (λ1 ≥ 10 `tol`), not a pole or a thin strip.
pub(super) fn flat_and_wide(m: &Moments, tol: f64) -> Option<Plane> {
    flat_and(m, tol, 10.0 * tol)
}

/// The least-squares plane of `m` when it is flat (λ0 ≤ `tol`) and spread at least `spread`
/// along both in-plane axes (√λ1).
pub(super) fn flat_and(m: &Moments, tol: f64, spread: f64) -> Option<Plane> {
    m.eigen()
        .filter(|(_, l, _)| l[0].sqrt() <= tol && l[1].sqrt() >= spread)
        .map(|(c, _, v)| Plane {
            n: v[0],
            d: v[0][0] * c[0] + v[0][1] * c[1] + v[0][2] * c[2],
        })
}

/// Point indices per node (counting sort of `point_node`, [`NONE`]: no node), in point order.
pub(super) struct Members {
    start: Vec<u32>,
    idx: Vec<u32>,
}

impl Members {
    pub(super) fn new(point_node: &[u32], nodes: usize) -> Self {
        let mut start = vec![0u32; nodes + 1];
        for &nd in point_node.iter().filter(|&&nd| nd != NONE) {
            start[nd as usize + 1] += 1;
        }
        for i in 0..nodes {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut idx = vec![0u32; start[nodes] as usize];
        for (i, &nd) in point_node.iter().enumerate() {
            if nd != NONE {
                idx[fill[nd as usize] as usize] = i as u32;
                fill[nd as usize] += 1;
            }
        }
        Members { start, idx }
    }

    pub(super) fn of(&self, nd: usize) -> &[u32] {
        &self.idx[self.start[nd] as usize..self.start[nd + 1] as usize]
    }
}

/// Least points for a dominant plane; RANSAC hypotheses; points scored per hypothesis.
const DOMINANT_MIN_POINTS: usize = 30;
const DOMINANT_HYPOTHESES: usize = 48;
const DOMINANT_SCORED: usize = 256;

/// The plane holding at least `fraction` of the points `idx` within `tol` (RANSAC over
/// triplets drawn by a generator seeded from the points, so the result depends on the points
/// alone, not on threads), refitted to its inliers and then flat and wide as
/// [`flat_and_wide`] asks; `None` when no plane holds that share.
pub(super) fn dominant_plane(
    xyz: &[[f64; 3]],
    idx: &[u32],
    origin: [f64; 3],
    tol: f64,
    fraction: f64,
) -> Option<Plane> {
    if fraction <= 0.0 || idx.len() < DOMINANT_MIN_POINTS {
        return None;
    }
    let pt = |i: u32| {
        let p = xyz[i as usize];
        [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]]
    };
    // Hypotheses are scored on an even subsample of at most DOMINANT_SCORED points.
    let step = idx.len().div_ceil(DOMINANT_SCORED);
    let scored: Vec<[f64; 3]> = idx.iter().step_by(step).map(|&i| pt(i)).collect();
    let seed = idx.len() as u64 ^ (idx[0] as u64) << 32;
    let mut rng = crate::rng::Rng(seed);
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..DOMINANT_HYPOTHESES {
        let [a, b, c] = [0; 3].map(|_| scored[rng.below(scored.len() as u32) as usize]);
        // Collinear or repeated points span no plane.
        let Some(pl) = Plane::through(&a, &b, &c, 1e-6) else {
            continue;
        };
        let count = scored.iter().filter(|q| pl.dist(q) <= tol).count();
        if best.is_none_or(|(k, _)| count > k) {
            best = Some((count, pl));
        }
    }
    let (_, Plane { n, d }) = best?;
    // Refit to every point within the tolerance; the refitted plane must hold the share.
    let mut inliers = Moments::new([0.0; 3]);
    for &i in idx {
        let q = pt(i);
        if (n[0] * q[0] + n[1] * q[1] + n[2] * q[2] - d).abs() <= tol {
            inliers.add(&q);
        }
    }
    if (inliers.n as f64) < fraction * idx.len() as f64 {
        return None;
    }
    let local = flat_and_wide(&inliers, tol)?;
    let held = idx.iter().filter(|&&i| local.dist(&pt(i)) <= tol).count();
    if (held as f64) < fraction * idx.len() as f64 {
        return None;
    }
    // Back to the tile's coordinates (the points above are relative to `origin`).
    let shift: f64 = (0..3).map(|k| local.n[k] * origin[k]).sum();
    Some(Plane {
        n: local.n,
        d: local.d + shift,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a grid of `step` over the rectangle `x0..x1` × `z0..z1` in the plane y = `y`.
    fn wall(x: (f64, f64), z: (f64, f64), y: f64, step: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        let (nx, nz) = (((x.1 - x.0) / step) as usize, ((z.1 - z.0) / step) as usize);
        for i in 0..nx {
            for k in 0..nz {
                v.push([
                    x.0 + (i as f64 + 0.5) * step,
                    y,
                    z.0 + (k as f64 + 0.5) * step,
                ]);
            }
        }
        v
    }

    /// The surface of a box `min..max`, points every `step`.
    fn boxed(min: [f64; 3], max: [f64; 3], step: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        let n = |a: f64, b: f64| ((b - a) / step).round() as usize;
        let (nx, ny, nz) = (n(min[0], max[0]), n(min[1], max[1]), n(min[2], max[2]));
        for i in 0..=nx {
            for j in 0..=ny {
                for k in 0..=nz {
                    let on = [i == 0 || i == nx, j == 0 || j == ny, k == 0 || k == nz];
                    if on.iter().any(|&b| b) {
                        let f = |a: f64, i: usize| a + i as f64 * step;
                        v.push([f(min[0], i), f(min[1], j), f(min[2], k)]);
                    }
                }
            }
        }
        v
    }

    struct Scene {
        xyz: Vec<[f64; 3]>,
        labels: Vec<u32>,
        lab: Vec<[f32; 3]>,
    }

    impl Scene {
        fn new() -> Self {
            Scene {
                xyz: Vec::new(),
                labels: Vec::new(),
                lab: Vec::new(),
            }
        }
        fn add(
            &mut self,
            pts: Vec<[f64; 3]>,
            label: u32,
            colour: [f32; 3],
        ) -> std::ops::Range<usize> {
            let a = self.xyz.len();
            self.labels.extend(std::iter::repeat_n(label, pts.len()));
            self.lab.extend(std::iter::repeat_n(colour, pts.len()));
            self.xyz.extend(pts);
            a..self.xyz.len()
        }
        fn refine(&mut self) -> Refined {
            let segments = self.labels.iter().copied().max().unwrap_or(0);
            let wanted = vec![true; self.xyz.len()];
            refine(
                &self.xyz,
                &mut self.labels,
                segments,
                &wanted,
                Some(&self.lab),
                [0.0; 3],
                &RefineParams {
                    voxel_m: 0.25,
                    plane_tolerance_m: 0.05,
                    dominant_fraction: 0.6,
                    colour_tolerance: 10.0,
                    stem_radius_m: 0.3,
                    stem_min_height_m: 1.0,
                    apart_voxel_m: 0.5,
                    split_colours: true,
                    attach_grows: true,
                },
            )
        }
        /// The one label of `r`'s points (panics if they differ).
        fn one(&self, r: &std::ops::Range<usize>) -> u32 {
            let l = self.labels[r.start];
            assert!(
                self.labels[r.clone()].iter().all(|&x| x == l),
                "points of one surface split"
            );
            l
        }
    }

    const WALL: [f32; 3] = [70.0, 5.0, 20.0];
    const GLASS: [f32; 3] = [20.0, 0.0, -5.0];

    /// A scan put a window's right half (10 cm behind the wall, in the wall's colour: its
    /// frame) into the wall's segment; its left half is a segment of its own, in the glass's
    /// colour. The refinement splits the right half off the wall's plane and joins it to the
    /// left half, whose plane it lies on, although their colours differ.
    #[test]
    fn a_window_behind_its_wall_is_split_off_and_joins_its_other_half() {
        let mut s = Scene::new();
        let win = |x: f64, pt: &[f64; 3]| pt[0] >= x && pt[0] < 3.2 && pt[2] >= 1.0 && pt[2] < 2.2;
        let w: Vec<[f64; 3]> = wall((0.0, 6.0), (0.0, 3.0), 0.0, 0.05)
            .into_iter()
            .filter(|p| !win(2.0, p))
            .collect();
        let glass = wall((2.0, 3.2), (1.0, 2.2), 0.1, 0.05);
        let (left, right): (Vec<_>, Vec<_>) = glass.into_iter().partition(|p| p[0] < 2.6);
        let wall_pts = s.add(w, 1, WALL);
        let right = s.add(right, 1, WALL);
        let left = s.add(left, 2, GLASS);
        let r = s.refine();
        assert_eq!(r.split_off, 1);
        let (lw, lr, ll) = (s.one(&wall_pts), s.one(&right), s.one(&left));
        assert_ne!(lw, lr, "the window stayed in the wall");
        assert_eq!(lr, ll, "the window's halves stayed apart");
        assert_eq!(r.segments, 2);
    }

    /// Unsegmented points within the tolerance of a segment's plane join it; the others form
    /// segments of their own where they are enough (10 points), else stay unsegmented.
    #[test]
    fn unsegmented_points_join_a_plane_or_form_pieces() {
        let mut s = Scene::new();
        let w = s.add(wall((0.0, 4.0), (0.0, 3.0), 0.0, 0.1), 1, WALL);
        let near = s.add(wall((1.0, 2.0), (1.0, 1.5), 0.03, 0.1), 0, WALL);
        let box_pts = s.add(wall((1.0, 1.5), (1.0, 1.4), -1.0, 0.1), 0, GLASS);
        let few = s.add(wall((3.0, 3.2), (2.0, 2.2), -1.0, 0.1), 0, GLASS);
        let r = s.refine();
        assert_eq!(r.attached, near.len());
        assert_eq!(s.one(&near), s.one(&w));
        let b = s.one(&box_pts);
        assert!(b != 0 && b != s.one(&w));
        assert_eq!(s.one(&few), 0, "{} points are no segment", few.len());
        assert_eq!(r.leftover_segments, 1);
    }

    /// A car's glass (a small flat patch the scans found apart) joins the car's body that
    /// encloses it; a smaller car parked 0.3 m behind touches the first in a few voxels only
    /// and stays apart.
    #[test]
    fn an_object_takes_what_it_encloses_but_not_its_neighbour() {
        let mut s = Scene::new();
        let body = s.add(boxed([0.0, 0.0, 0.0], [4.0, 1.8, 1.4], 0.05), 1, WALL);
        // Glass just above the roof, 1 m x 0.6 m.
        let glass = s.add(
            wall((1.5, 2.5), (0.6, 1.2), 0.0, 0.05)
                .into_iter()
                .map(|p| [p[0], p[2], 1.42])
                .collect(),
            2,
            GLASS,
        );
        let other = s.add(boxed([4.3, 0.0, 0.0], [7.3, 1.8, 1.4], 0.05), 3, GLASS);
        // A side window 0.5 m wide and 1.2 m tall: as narrow and tall as a stem, but flat.
        let side = s.add(wall((2.0, 2.5), (0.1, 1.3), -0.02, 0.05), 4, GLASS);
        s.refine();
        assert_eq!(
            s.one(&glass),
            s.one(&body),
            "the glass stayed apart from its car"
        );
        assert_eq!(s.one(&side), s.one(&body), "the side window stayed apart");
        assert_ne!(s.one(&other), s.one(&body), "two cars joined");
    }

    /// A scan joined a parked car and the façade 5 m behind it (through the footpath, which
    /// is ground and no member here) and the ties kept them one segment. The refinement
    /// splits the façade's part off, and that part, in its own colour, does not join the
    /// neighbouring façade of another colour in its plane.
    #[test]
    fn a_car_and_the_facade_behind_it_are_split_apart() {
        let mut s = Scene::new();
        let car = s.add(
            boxed([0.0, 0.0, 0.0], [4.0, 1.8, 1.4], 0.05),
            1,
            [50.0, 0.0, 0.0],
        );
        let part = s.add(wall((0.0, 3.0), (0.0, 3.0), 6.8, 0.05), 1, WALL);
        let next = s.add(wall((3.0, 8.0), (0.0, 3.0), 6.8, 0.05), 2, GLASS);
        let r = s.refine();
        assert_eq!(r.apart, 1);
        assert_ne!(
            s.one(&car),
            s.one(&part),
            "the car kept the façade behind it"
        );
        assert_ne!(s.one(&part), s.one(&next), "façades of two colours joined");
        assert_ne!(s.one(&car), 0);
    }

    /// Two buildings' façades in one plane, in two colours, came out of the ties as one
    /// segment: they are split by colour. A brick wall, two colours mixed in every voxel, stays
    /// one segment.
    #[test]
    fn two_facades_in_one_plane_are_split_by_colour_a_brick_wall_is_not() {
        let mut s = Scene::new();
        let cream = s.add(wall((0.0, 6.0), (0.0, 3.0), 0.0, 0.05), 1, WALL);
        let white = s.add(wall((6.0, 12.0), (0.0, 3.0), 0.0, 0.05), 1, GLASS);
        let brick = s.add(wall((0.0, 6.0), (0.0, 3.0), 5.0, 0.05), 2, WALL);
        // Courses 0.1 m high, alternating: every voxel holds both colours, 60/40 either way.
        for i in brick.clone() {
            if (s.xyz[i][2] / 0.1).floor() as i64 % 2 == 1 {
                s.lab[i] = GLASS;
            }
        }
        let r = s.refine();
        assert_eq!(r.apart, 1);
        assert_ne!(s.one(&cream), s.one(&white), "the façades stayed one");
        assert_ne!(s.one(&brick), 0);
    }

    /// A façade band no scan segmented lies between its façade (short, in its colour) and the
    /// neighbouring façade (tall, in another colour) in one plane. The band's ends join the
    /// planes they touch; its middle, a piece, takes the plane of its own colour although it
    /// touches the other façade more — taking either had chained the two façades.
    #[test]
    fn a_piece_joins_the_plane_of_its_own_colour() {
        let mut s = Scene::new();
        let own = s.add(wall((0.0, 4.0), (0.0, 1.0), 0.0, 0.05), 1, WALL);
        let band = s.add(wall((4.0, 8.0), (0.0, 3.0), 0.0, 0.05), 0, WALL);
        let other = s.add(wall((8.0, 12.0), (0.0, 3.0), 0.0, 0.05), 2, GLASS);
        s.refine();
        assert_ne!(s.one(&own), s.one(&other), "the two façades joined");
        let middle = (band.start..band.end)
            .find(|&i| (s.xyz[i][0] - 6.0).abs() < 0.03 && (s.xyz[i][2] - 1.5).abs() < 0.03)
            .expect("a point in the band's middle");
        assert_eq!(
            s.labels[middle],
            s.one(&own),
            "the band's middle left its façade"
        );
    }

    /// A façade band no scan segmented continues its façade for 5 m, with a window 10 cm
    /// behind it: the band attaches to the façade across its width, pass by pass; the window is
    /// left over and becomes a segment of its own. A small flat patch (a crown's or a car's
    /// part) does not grow so: of the points in its plane beyond it, only those next to it
    /// attach. (Growing through points of another colour only: `a_piece_joins_…`.)
    #[test]
    fn unsegmented_points_attach_across_a_wide_plane_only() {
        let mut s = Scene::new();
        let facade = s.add(wall((0.0, 3.0), (0.0, 3.0), 0.0, 0.05), 1, WALL);
        let band = s.add(wall((3.0, 8.0), (0.0, 3.0), 0.0, 0.05), 0, WALL);
        let window = s.add(wall((5.0, 6.0), (1.0, 2.0), -0.1, 0.05), 0, GLASS);
        let r = s.refine();
        assert_eq!(
            s.one(&band),
            s.one(&facade),
            "the band did not join its façade"
        );
        assert!(
            r.attached >= band.len(),
            "{} of {} attached",
            r.attached,
            band.len()
        );
        assert_ne!(s.one(&window), 0);
        assert_ne!(
            s.one(&window),
            s.one(&facade),
            "the window joined the façade"
        );
        // A flat patch 0.6 m square (a plane, not a wide one) and points in its plane beyond:
        // only those next to the patch attach.
        let mut s = Scene::new();
        s.add(wall((0.0, 0.6), (0.0, 0.6), 0.0, 0.05), 1, GLASS);
        let beyond = s.add(wall((0.6, 4.0), (0.0, 0.6), 0.0, 0.05), 0, GLASS);
        let r = s.refine();
        assert!(
            2 * r.attached < beyond.len(),
            "a small patch's plane grew: {} of {} attached",
            r.attached,
            beyond.len()
        );
    }

    /// Points no segment took — a façade band with a window 10 cm behind it — form one piece;
    /// it is split off its dominant plane as the world segments are, so the window does not
    /// join the façade with the band.
    #[test]
    fn a_leftover_piece_is_split_off_its_plane() {
        let mut s = Scene::new();
        // (2.4 m tall: a dominant plane spreads ≥ 0.5 m, one σ, both ways.)
        let band = s.add(wall((0.0, 6.0), (0.0, 2.4), 0.0, 0.05), 0, WALL);
        let window = s.add(wall((2.0, 3.0), (0.8, 1.4), -0.1, 0.05), 0, GLASS);
        s.refine();
        assert_ne!(s.one(&band), 0);
        assert_ne!(s.one(&window), 0);
        assert_ne!(s.one(&band), s.one(&window), "the window joined the band");
    }

    /// Points on a vertical cylinder about (`cx`, `cy`) of radius `r` from `z0` to `z1`, at
    /// azimuths `a0..a1` (radians), about every `step`.
    fn cylinder(c: [f64; 2], r: f64, z: (f64, f64), a: (f64, f64), step: f64) -> Vec<[f64; 3]> {
        let na = ((a.1 - a.0) * r / step).ceil() as usize;
        let nz = ((z.1 - z.0) / step) as usize;
        let mut v = Vec::new();
        for i in 0..na {
            let t = a.0 + (i as f64 + 0.5) * (a.1 - a.0) / na as f64;
            for k in 0..nz {
                let zk = z.0 + (k as f64 + 0.5) * step;
                v.push([c[0] + r * t.cos(), c[1] + r * t.sin(), zk]);
            }
        }
        v
    }

    /// Points on the surface of an ellipsoid of half-axes `a` (horizontal) and `b` (vertical)
    /// about `c`, about every `step`.
    fn ellipsoid(c: [f64; 3], a: f64, b: f64, step: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        let nl = (std::f64::consts::PI * b / step) as usize;
        for i in 0..nl {
            let phi = std::f64::consts::PI * (i as f64 + 0.5) / nl as f64;
            let ring = a * phi.sin();
            let n = ((std::f64::consts::TAU * ring / step).ceil() as usize).max(1);
            for j in 0..n {
                let t = std::f64::consts::TAU * j as f64 / n as f64;
                v.push([
                    c[0] + ring * t.cos(),
                    c[1] + ring * t.sin(),
                    c[2] - b * phi.cos(),
                ]);
            }
        }
        v
    }

    const BARK: [f32; 3] = [35.0, 8.0, 15.0];
    const LEAVES: [f32; 3] = [45.0, -30.0, 35.0];

    /// A tree whose trunk the scans saw from one side (the road's: a half-cylinder, which
    /// passes for flat within 5 cm) and from `foot` up, under a crown reaching down to 1.8 m.
    fn tree(s: &mut Scene, foot: f64, trunk: u32, crown: u32) -> [std::ops::Range<usize>; 3] {
        let side = (0.0, std::f64::consts::PI);
        let low = s.add(
            cylinder([0.0, 0.0], 0.15, (foot, 1.8), side, 0.05),
            trunk,
            BARK,
        );
        // The trunk's top, inside the crown's lowest part.
        let top = s.add(
            cylinder([0.0, 0.0], 0.15, (1.8, 2.5), side, 0.05),
            trunk,
            BARK,
        );
        let c = ellipsoid([0.0, 0.0, 3.8], 2.0, 2.0, 0.1);
        let crown_pts = s.add(c, crown, LEAVES);
        [low, top, crown_pts]
    }

    /// One world segment holding a trunk and its crown (a scan's cues joined them where the
    /// trunk enters the crown): the stem is split off and stays apart.
    #[test]
    fn a_trunk_is_split_off_its_crown() {
        let mut s = Scene::new();
        let [low, top, crown] = tree(&mut s, 0.5, 1, 1);
        let r = s.refine();
        assert_eq!(r.stems, 1);
        let trunk = s.one(&low);
        assert_eq!(s.one(&top), trunk, "the trunk's top went with the crown");
        // The crown's points off the stem's axis keep one label; the few at its bottom within
        // the stem's radius (about the axis of its visible side) go with the stem.
        let crown_labels: Vec<u32> = s.labels[crown.clone()]
            .iter()
            .zip(&s.xyz[crown])
            .filter(|(_, q)| q[0].hypot(q[1]) > 0.45)
            .map(|(&l, _)| l)
            .collect();
        assert!(crown_labels.iter().all(|&l| l == crown_labels[0]));
        assert!(crown_labels[0] != 0 && crown_labels[0] != trunk);
    }

    /// A trunk and its crown as two segments, the trunk seen from 1.4 m up (parked cars hid
    /// its foot): it touches the crown with most of its voxels, as a car's glass touches the
    /// car, but a stem is not enclosed by a crown.
    #[test]
    fn a_trunk_is_not_enclosed_by_its_crown() {
        let mut s = Scene::new();
        let [low, top, crown] = tree(&mut s, 1.4, 1, 2);
        let r = s.refine();
        assert_eq!(r.stems, 0);
        let trunk = s.one(&low);
        assert_eq!(s.one(&top), trunk);
        assert_ne!(s.one(&crown), trunk, "the trunk joined its crown");
    }

    /// A pole with an arm at its top stays one segment: nothing rises above its stem.
    #[test]
    fn a_pole_keeps_its_arm() {
        let mut s = Scene::new();
        let tau = std::f64::consts::TAU;
        let mut pts = cylinder([0.0, 0.0], 0.1, (0.0, 6.0), (0.0, tau), 0.05);
        pts.extend((0..40).flat_map(|i| {
            let x = 0.1 + i as f64 * 0.04;
            [
                [x, 0.0, 5.85],
                [x, 0.0, 5.95],
                [x, 0.05, 5.9],
                [x, -0.05, 5.9],
            ]
        }));
        let pole = s.add(pts, 1, BARK);
        let r = s.refine();
        assert_eq!(r.stems, 0);
        assert_eq!(r.segments, 1);
        assert_ne!(s.one(&pole), 0);
    }

    /// Two touching segments in one plane are one surface when their colours agree, two
    /// buildings' façades when they do not.
    #[test]
    fn coplanar_neighbours_join_by_colour() {
        for (colour, joined) in [([72.0, 6.0, 21.0], true), ([70.0, 35.0, 20.0], false)] {
            let mut s = Scene::new();
            let a = s.add(wall((0.0, 3.0), (0.0, 3.0), 0.0, 0.1), 1, WALL);
            let b = s.add(wall((3.0, 6.0), (0.0, 3.0), 0.0, 0.1), 2, colour);
            s.refine();
            assert_eq!(s.one(&a) == s.one(&b), joined, "colour {colour:?}");
        }
    }
}
