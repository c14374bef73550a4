//! Region growing (thesis §3.5.4 and Table 3-1 steps 3–4; Rabbani et al. 2006 for the
//! smoothness-constraint mode). Sequential by design: every decision depends on the labels
//! the previous ones left, and the visiting order is canonical, which is what makes the
//! result independent of input order and thread count.

use std::collections::VecDeque;

use super::features::{cdist, Moments, Plane};
use super::neighbours::Neighbours;
use super::seed::{seed_plane, HoughGrid, Scratch};
use super::{Mode, SegParams};

/// A segment while growing.
#[derive(Debug, Clone)]
pub struct Seg {
    /// Current plane (refitted every `refit_every` additions and at the end of growing).
    pub plane: Plane,
    /// Moments of the member points.
    pub mom: Moments,
    /// Sum of member colours (CIELab).
    pub csum: [f64; 3],
}

impl Seg {
    fn mean_lab(&self) -> [f64; 3] {
        let inv = 1.0 / self.mom.n.max(1) as f64;
        self.csum.map(|c| c * inv)
    }

    fn add(&mut self, p: &[f64; 3], lab: Option<&[f32; 3]>) {
        self.mom.add(p);
        if let Some(l) = lab {
            for (s, v) in self.csum.iter_mut().zip(l) {
                *s += *v as f64;
            }
        }
    }

    fn remove(&mut self, p: &[f64; 3], lab: Option<&[f32; 3]>) {
        self.mom.remove(p);
        if let Some(l) = lab {
            for (s, v) in self.csum.iter_mut().zip(l) {
                *s -= *v as f64;
            }
        }
    }

    fn refit(&mut self) {
        if let Some((pl, _)) = self.mom.plane() {
            self.plane = pl;
        }
    }
}

/// Everything the growing reads, already in canonical point order.
pub struct Input<'a> {
    /// Coordinates, centred.
    pub pts: &'a [[f64; 3]],
    /// CIELab colour per point, when colour takes part.
    pub lab: Option<&'a [[f32; 3]]>,
    /// Neighbour lists.
    pub nb: &'a Neighbours,
    /// Local normal and curvature per point.
    pub normals: &'a [([f32; 3], f32)],
    /// Seed visiting order.
    pub order: &'a [u32],
}

/// Result of growing: a label per point (0 = none, else 1-based index into `segs`).
pub struct Grown {
    /// Labels in canonical point order.
    pub labels: Vec<u32>,
    /// Segments by label − 1 (some may be empty after edge reassignment).
    pub segs: Vec<Seg>,
    /// Seed planes tried.
    pub seeds_tried: usize,
    /// Points attached from the eligible list.
    pub eligible_attached: usize,
}

struct Grower<'a, 'b> {
    inp: &'b Input<'a>,
    p: &'b SegParams,
    labels: Vec<u32>,
    segs: Vec<Seg>,
    eligible: Vec<u32>,
    is_eligible: Vec<bool>,
    rg2: f32,
    cos_edge: f64,
    queue: VecDeque<u32>,
}

impl Grower<'_, '_> {
    fn lab(&self, i: usize) -> Option<&[f32; 3]> {
        self.inp.lab.map(|l| &l[i])
    }

    /// Colour criteria of §3.5.4: distance to the mean of the *local* region (members of
    /// segment `id` adjacent to the candidate `q`, plus the region point `p`) below `c_thl`,
    /// and to the *global* region mean below `c_thg`.
    fn colour_ok(&self, id: u32, p: usize, q: usize) -> bool {
        let Some(lab) = self.inp.lab else {
            return true;
        };
        let seg = &self.segs[id as usize - 1];
        if cdist(&lab[q], &seg.mean_lab()) >= self.p.c_thg {
            return false;
        }
        let mut acc = lab[p].map(|c| c as f64);
        let mut n = 1.0;
        for &t in self.inp.nb.within(q, self.rg2) {
            if t as usize != p && self.labels[t as usize] == id {
                for c in 0..3 {
                    acc[c] += lab[t as usize][c] as f64;
                }
                n += 1.0;
            }
        }
        cdist(&lab[q], &acc.map(|c| c / n)) < self.p.c_thl
    }

    fn mark_eligible(&mut self, q: usize) {
        if self.labels[q] == 0 && !self.is_eligible[q] {
            self.is_eligible[q] = true;
            self.eligible.push(q as u32);
        }
    }

    /// Edge test for a candidate already in segment `other` (§3.5.4 "Consideration of
    /// edges"): only when the planes meet at more than `edge_angle_deg`, and only if the RMS
    /// distance of the candidate and its `edge_k` nearest neighbours is smaller to the
    /// current plane than to the other segment's plane.
    fn edge_prefers_current(&self, cur: &Plane, other: u32, q: usize) -> bool {
        let op = &self.segs[other as usize - 1].plane;
        let dot = (cur.n[0] * op.n[0] + cur.n[1] * op.n[1] + cur.n[2] * op.n[2]).abs();
        if dot > self.cos_edge {
            return false;
        }
        let pts = self.inp.pts;
        let (mut sc, mut so) = (cur.dist(&pts[q]).powi(2), op.dist(&pts[q]).powi(2));
        let nbq = self.inp.nb.within(q, self.rg2);
        for &t in &nbq[..nbq.len().min(self.p.edge_k)] {
            sc += cur.dist(&pts[t as usize]).powi(2);
            so += op.dist(&pts[t as usize]).powi(2);
        }
        sc < so
    }

    fn new_segment(&mut self, plane: Plane, members: &[u32]) -> u32 {
        let origin = self.inp.pts[members[0] as usize];
        let mut seg = Seg {
            plane,
            mom: Moments::new(origin),
            csum: [0.0; 3],
        };
        let id = self.segs.len() as u32 + 1;
        for &m in members {
            let m = m as usize;
            seg.add(&self.inp.pts[m], self.lab(m));
            self.labels[m] = id;
            self.queue.push_back(m as u32);
        }
        self.segs.push(seg);
        id
    }

    fn grow_planar(&mut self, id: u32) {
        let si = id as usize - 1;
        let pts = self.inp.pts;
        let mut since_refit = 0usize;
        while let Some(pi) = self.queue.pop_front() {
            let pi = pi as usize;
            for &q in self.inp.nb.within(pi, self.rg2) {
                let q = q as usize;
                let lq = self.labels[q];
                if lq == id {
                    continue;
                }
                let plane = self.segs[si].plane;
                if plane.dist(&pts[q]) >= self.p.d_thg_m {
                    continue;
                }
                if lq != 0 && !self.edge_prefers_current(&plane, lq, q) {
                    continue;
                }
                if !self.colour_ok(id, pi, q) {
                    self.mark_eligible(q);
                    continue;
                }
                if lq != 0 {
                    let lab = self.inp.lab.map(|l| &l[q]);
                    self.segs[lq as usize - 1].remove(&pts[q], lab);
                }
                let lab = self.inp.lab.map(|l| &l[q]);
                self.segs[si].add(&pts[q], lab);
                self.labels[q] = id;
                self.queue.push_back(q as u32);
                since_refit += 1;
                if since_refit >= self.p.refit_every {
                    self.segs[si].refit();
                    since_refit = 0;
                }
            }
        }
        self.segs[si].refit();
    }

    fn grow_smooth(&mut self, id: u32, cos_angle: f64, curvature: f64) {
        let si = id as usize - 1;
        let pts = self.inp.pts;
        let nrm = self.inp.normals;
        while let Some(pi) = self.queue.pop_front() {
            let pi = pi as usize;
            let np = nrm[pi].0;
            for &q in self.inp.nb.within(pi, self.rg2) {
                let q = q as usize;
                if self.labels[q] != 0 {
                    continue;
                }
                let nq = nrm[q].0;
                let dot = (np[0] * nq[0] + np[1] * nq[1] + np[2] * nq[2]).abs() as f64;
                if dot < cos_angle {
                    continue;
                }
                if !self.colour_ok(id, pi, q) {
                    self.mark_eligible(q);
                    continue;
                }
                let lab = self.inp.lab.map(|l| &l[q]);
                self.segs[si].add(&pts[q], lab);
                self.labels[q] = id;
                if (nrm[q].1 as f64) < curvature {
                    self.queue.push_back(q as u32);
                }
            }
        }
        self.segs[si].refit();
    }

    /// Table 3-1, last loop: each eligible point still unlabelled joins the labelled
    /// neighbour (within `r_grow`) whose segment passes the geometric test and whose colour
    /// is closest. Decisions read a snapshot of the labels, so they do not cascade.
    fn attach_eligible(&mut self) -> usize {
        let mut el = std::mem::take(&mut self.eligible);
        el.sort_unstable();
        let snapshot = self.labels.clone();
        let pts = self.inp.pts;
        let mut attached = 0;
        for &q in &el {
            let q = q as usize;
            if snapshot[q] != 0 {
                continue;
            }
            let mut best: Option<(f64, u32)> = None;
            for &t in self.inp.nb.within(q, self.rg2) {
                let s = snapshot[t as usize];
                if s == 0 {
                    continue;
                }
                let ok = match self.p.mode {
                    Mode::Planar => self.segs[s as usize - 1].plane.dist(&pts[q]) < self.p.d_thg_m,
                    Mode::Smooth { angle_deg, .. } => {
                        let (a, b) = (self.inp.normals[q].0, self.inp.normals[t as usize].0);
                        let dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).abs() as f64;
                        dot >= angle_deg.to_radians().cos()
                    }
                };
                if !ok {
                    continue;
                }
                let cd = match self.inp.lab {
                    Some(l) => cdist(&l[q], &l[t as usize].map(|c| c as f64)),
                    None => 0.0,
                };
                if best.is_none_or(|b| cd < b.0) {
                    best = Some((cd, s));
                }
            }
            if let Some((_, s)) = best {
                let lab = self.inp.lab.map(|l| &l[q]);
                self.segs[s as usize - 1].add(&pts[q], lab);
                self.labels[q] = s;
                attached += 1;
            }
        }
        attached
    }
}

/// Runs seed selection and growing over all points, then attaches eligible points.
pub fn grow(inp: &Input<'_>, p: &SegParams) -> Grown {
    let n = inp.pts.len();
    let mut g = Grower {
        inp,
        p,
        labels: vec![0; n],
        segs: Vec::new(),
        eligible: Vec::new(),
        is_eligible: vec![false; n],
        rg2: (p.r_grow_m * p.r_grow_m) as f32,
        cos_edge: p.edge_angle_deg.to_radians().cos(),
        queue: VecDeque::new(),
    };
    let rs2 = (p.r_seed_m * p.r_seed_m) as f32;
    let grid = HoughGrid::new(p.a_b_deg);
    let mut scratch = Scratch::default();
    let mut cand = Vec::with_capacity(p.k);
    let mut tried = 0usize;
    for &s in inp.order {
        let s = s as usize;
        if g.labels[s] != 0 {
            continue;
        }
        match p.mode {
            Mode::Planar => {
                cand.clear();
                cand.extend(
                    inp.nb
                        .within(s, rs2)
                        .iter()
                        .copied()
                        .filter(|&j| g.labels[j as usize] == 0),
                );
                if cand.len() + 1 < p.n_min {
                    continue;
                }
                tried += 1;
                let Some((plane, members)) =
                    seed_plane(s, &cand, inp.pts, inp.lab, p, &grid, &mut scratch)
                else {
                    continue;
                };
                let id = g.new_segment(plane, &members);
                g.grow_planar(id);
            }
            Mode::Smooth {
                angle_deg,
                curvature,
            } => {
                tried += 1;
                let plane = Plane {
                    n: [0.0, 0.0, 1.0],
                    d: 0.0,
                };
                let id = g.new_segment(plane, &[s as u32]);
                g.grow_smooth(id, angle_deg.to_radians().cos(), curvature);
            }
        }
    }
    let eligible_attached = g.attach_eligible();
    Grown {
        labels: g.labels,
        segs: g.segs,
        seeds_tried: tried,
        eligible_attached,
    }
}
