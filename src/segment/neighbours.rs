//! Fixed-size neighbourhood lists: the `k` nearest points within a radius, for every point.
//!
//! The lists are built once per call (Table 3-1 step 1, thesis §3.5.1) and stored in
//! fixed-width rows (`k` slots per point and a count), sorted by distance (as f32) with ties
//! broken by point index. The searches write the rows in place: no list is allocated per
//! point and nothing is packed afterwards, so a stage's neighbour memory is `8k + 4` bytes
//! per point at its peak (per-point lists followed by a packed copy peaked at about twice
//! that: ~370 bytes a point at k = 20, the segment stage's largest allocation). Because the
//! caller hands us the points already in a canonical order, the lists — and everything
//! computed from them — do not depend on the input order.
//!
//! Two searches are available, a kd-tree (`kiddo::ImmutableKdTree`, built per call) and a
//! hashed voxel grid whose cell width adapts to the data ([`knn_voxel`]). Measured with
//! `cargo run --release --example neighbour_bench /tmp/seg_synth.bin` (2 shared cores, load
//! ≈ 1.2–1.5 from other users, rayon 2 threads, k = 20, best of 3):
//!
//! | cloud                                                   | kd-tree | voxel grid |
//! |---------------------------------------------------------|---------|------------|
//! | synth tile, 195 k non-ground pts (roofs, walls, trees), r = 1.75 m | 0.479 s | 0.432 s |
//! | 2.5-D: 1 M pts on a 200 × 200 × 0.06 m slab, r = 1.75 m | 5.60 s  | 2.40 s     |
//! | TLS façade + floor, 300 k pts, r = 0.25 m               | 1.06 s  | 0.94 s     |
//!
//! kiddo's tree splits the three axes in turn, so on a nearly coplanar cloud a third of its
//! levels split the flat axis and prune nothing; the grid's cost there is 27 hash look-ups
//! plus ~9 occupied cells of ~k points. The grid is faster on every cloud measured, so
//! [`NeighbourSearch::Auto`](super::NeighbourSearch) uses it; the kd-tree stays selectable.
//! Both return the same distances in every row (a unit test and an end-to-end test check the
//! lists on untied data), but among points tied at a row's `k`-th distance the grid keeps the
//! lowest indices and kiddo any of them: on the simulated drive's millimetre coordinates 411
//! of 198,220 rows of a tile held other indices (none other distances), and a run with the
//! kd-tree segmented 99.56 % of the drive's points alike (`scripts/agreement.py`). Measured
//! there (2026-11-28, `tessera run` of the 310 m drive of `scripts/bench_stages.sh`, one run
//! each): the segment stage's searches took 19.4 s with the grid and 69.6 s with the kd-tree.

use std::num::NonZeroUsize;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

/// Neighbours of all points: row `i` holds `cnt[i]` of its `k` slots.
#[derive(Debug, Clone, PartialEq)]
pub struct Neighbours {
    k: usize,
    cnt: Vec<u32>,
    idx: Vec<u32>,
    dist2: Vec<f32>,
}

impl Neighbours {
    /// Empty rows of width `k` for `n` points.
    fn rows(n: usize, k: usize) -> Self {
        Neighbours {
            k,
            cnt: vec![0; n],
            idx: vec![0; n * k],
            dist2: vec![0.0; n * k],
        }
    }

    /// Neighbours of point `i` (excluding `i`), nearest first.
    #[inline]
    pub fn of(&self, i: usize) -> &[u32] {
        &self.idx[i * self.k..i * self.k + self.cnt[i] as usize]
    }

    /// Squared distances matching [`Neighbours::of`].
    #[inline]
    pub fn dist2_of(&self, i: usize) -> &[f32] {
        &self.dist2[i * self.k..i * self.k + self.cnt[i] as usize]
    }

    /// Neighbours of `i` closer than `r` (squared: `r2`); a prefix of [`Neighbours::of`].
    #[inline]
    pub fn within(&self, i: usize, r2: f32) -> &[u32] {
        let d = self.dist2_of(i);
        let n = d.partition_point(|&x| x <= r2);
        &self.of(i)[..n]
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.cnt.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Fills every row in parallel: `query(i, prev, cand)` leaves point `i`'s candidates in
    /// `cand` (any order, at least its `k` nearest), and the row keeps the `k` nearest by
    /// (distance, index). Rows are processed in blocks of consecutive points (the callers'
    /// points are in a spatially coherent order); `prev` is the `k`-th squared distance of row
    /// `i − 1` when that row was just computed and is full, which a query may use to bound its
    /// own search. `S` is a query's scratch, one per thread, kept from one row to the next.
    fn fill<S: Default + Send>(
        n: usize,
        k: usize,
        query: impl Fn(usize, Option<f32>, &mut Vec<u64>, &mut S) + Sync,
    ) -> Self {
        let mut nb = Neighbours::rows(n, k);
        if k == 0 {
            return nb;
        }
        const BLOCK: usize = 1024;
        nb.idx
            .par_chunks_mut(BLOCK * k)
            .zip(nb.dist2.par_chunks_mut(BLOCK * k))
            .zip(nb.cnt.par_chunks_mut(BLOCK))
            .enumerate()
            .for_each_init(
                <(Vec<u64>, S)>::default,
                |(cand, scratch), (b, ((idx, dist2), cnt))| {
                    let mut prev = None;
                    for (o, c) in cnt.iter_mut().enumerate() {
                        cand.clear();
                        query(b * BLOCK + o, prev, cand, scratch);
                        finish(cand, k);
                        prev = (cand.len() == k).then(|| dist_of(cand[k - 1]));
                        for (t, &c) in cand.iter().enumerate() {
                            idx[o * k + t] = c as u32;
                            dist2[o * k + t] = dist_of(c);
                        }
                        *c = cand.len() as u32;
                    }
                },
            );
        nb
    }

    /// Moves the rows from the order they were computed in (row `q` belongs to point
    /// `order[q]`) to point order, in place, following the permutation's cycles with one
    /// row of scratch.
    fn unpermute(&mut self, order: &[u32]) {
        let k = self.k;
        let mut done = vec![false; order.len()];
        let (mut ti, mut td) = (vec![0u32; k], vec![0f32; k]);
        for start in 0..order.len() {
            if done[start] {
                continue;
            }
            ti.copy_from_slice(&self.idx[start * k..start * k + k]);
            td.copy_from_slice(&self.dist2[start * k..start * k + k]);
            let mut tc = self.cnt[start];
            let mut dest = order[start] as usize;
            loop {
                // The scratch row belongs to point `dest`: swap it in, carry what was there
                // (the row of point `order[dest]`).
                ti.swap_with_slice(&mut self.idx[dest * k..dest * k + k]);
                td.swap_with_slice(&mut self.dist2[dest * k..dest * k + k]);
                std::mem::swap(&mut tc, &mut self.cnt[dest]);
                done[dest] = true;
                if dest == start {
                    break;
                }
                dest = order[dest] as usize;
            }
        }
    }
}

/// A candidate packed in one integer: the bits of its f32 squared distance (which order like
/// the values for non-negative floats) above its point index, so that (distance, index) order
/// is integer order — selection and sorting compare plain `u64`s.
#[inline]
fn packed(d2: f32, j: u32) -> u64 {
    ((d2.to_bits() as u64) << 32) | j as u64
}

/// The squared distance of a [`packed`] candidate.
#[inline]
fn dist_of(c: u64) -> f32 {
    f32::from_bits((c >> 32) as u32)
}

/// Sorts by (distance, index) and keeps the first `k`: the canonical neighbour list.
fn finish(l: &mut Vec<u64>, k: usize) {
    if k > 0 && l.len() > k {
        l.select_nth_unstable(k - 1);
    }
    l.truncate(k);
    l.sort_unstable();
}

/// The `k` nearest neighbours of every point within `radius`, with a kd-tree.
pub fn knn_kdtree(pts: &[[f64; 3]], k: usize, radius: f64) -> Neighbours {
    if pts.is_empty() {
        return Neighbours::rows(0, k);
    }
    let tree: ImmutableKdTree<f64, u32, 3, 32> = ImmutableKdTree::new_from_slice(pts);
    // One extra: the query point itself comes back too.
    let want = NonZeroUsize::new(k + 1).unwrap_or(NonZeroUsize::MIN);
    let r2 = radius * radius;
    Neighbours::fill(pts.len(), k, |i, _, cand, _: &mut ()| {
        let found = tree.nearest_n_within::<SquaredEuclidean>(&pts[i], r2, want, true);
        cand.extend(
            found
                .into_iter()
                .filter(|nn| nn.item as usize != i)
                .map(|nn| packed(nn.distance as f32, nn.item)),
        );
    })
}

/// The `k` nearest neighbours within `radius` of points on a 2.5-D surface (terrain, road):
/// candidates are the `2k` nearest in xy from a 2-D kd-tree, ranked by their 3-D distance.
/// On such data a 3-D kd-tree cannot split usefully along z and both 3-D searches cost ~10 µs
/// a point at street-level densities (~2,000 pts/m²); the 2-D tree is several times faster.
/// Exact for surfaces that are single-valued in z; on steps (kerb faces) the xy candidates
/// still hold the nearest 3-D neighbours whenever fewer than `k` points lie directly above
/// or below.
pub fn knn_surface(pts: &[[f64; 3]], k: usize, radius: f64) -> Neighbours {
    if pts.is_empty() {
        return Neighbours::rows(0, k);
    }
    let xy: Vec<[f64; 2]> = pts.iter().map(|p| [p[0], p[1]]).collect();
    let tree: ImmutableKdTree<f64, u32, 2, 32> = ImmutableKdTree::new_from_slice(&xy);
    let want = NonZeroUsize::new(2 * k + 1).unwrap_or(NonZeroUsize::MIN);
    let r2 = radius * radius;
    Neighbours::fill(pts.len(), k, |i, _, cand, _: &mut ()| {
        let p = &pts[i];
        let found = tree.nearest_n::<SquaredEuclidean>(&xy[i], want);
        cand.extend(
            found
                .into_iter()
                .filter(|nn| nn.item as usize != i)
                .filter_map(|nn| {
                    let q = &pts[nn.item as usize];
                    let d2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2);
                    (d2 <= r2).then_some(packed(d2 as f32, nn.item))
                }),
        );
    })
}

/// Open-addressing hash table from packed cell coordinates to a range of the cell-sorted
/// point array (std's SipHash costs more than the distance tests it guards).
struct CellTable {
    mask: usize,
    /// 64 − log2(capacity): the slot is the top bits of the multiplied key.
    shift: u32,
    keys: Vec<u64>,
    ranges: Vec<(u32, u32)>,
}

impl CellTable {
    const EMPTY: u64 = u64::MAX;

    fn new(cells: usize) -> Self {
        let cap = (cells * 2).next_power_of_two().max(16);
        CellTable {
            mask: cap - 1,
            shift: 64 - cap.trailing_zeros(),
            keys: vec![Self::EMPTY; cap],
            ranges: vec![(0, 0); cap],
        }
    }

    #[inline]
    fn slot(&self, key: u64) -> usize {
        // Fibonacci hashing: the top bits of the product depend on every bit of the key. (The
        // low bits taken before ignored the x coordinate, packed at bit 42: a 2-D grid's cells
        // of one row all probed from one slot.)
        (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> self.shift) as usize
    }

    fn insert(&mut self, key: u64, r: (u32, u32)) {
        let mut i = self.slot(key);
        while self.keys[i] != Self::EMPTY {
            i = (i + 1) & self.mask;
        }
        self.keys[i] = key;
        self.ranges[i] = r;
    }

    #[inline]
    fn get(&self, key: u64) -> Option<(u32, u32)> {
        let mut i = self.slot(key);
        loop {
            let k = self.keys[i];
            if k == key {
                return Some(self.ranges[i]);
            }
            if k == Self::EMPTY {
                return None;
            }
            i = (i + 1) & self.mask;
        }
    }
}

/// Packs integer cell coordinates (each offset into 0..2^21) into one key.
#[inline]
fn pack(c: [i64; 3]) -> u64 {
    const OFF: i64 = 1 << 20;
    (((c[0] + OFF) as u64) << 42) | (((c[1] + OFF) as u64) << 21) | ((c[2] + OFF) as u64)
}

/// Mean number of points per occupied cell of width `c`.
fn occupancy(pts: &[[f64; 3]], lo: [f64; 3], c: f64) -> f64 {
    let mut keys: Vec<u64> = pts
        .iter()
        .map(|p| pack(std::array::from_fn(|d| ((p[d] - lo[d]) / c) as i64)))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    pts.len() as f64 / keys.len().max(1) as f64
}

/// Cell width of [`knn_voxel`] for points whose lower corner is `lo`: an occupied cell should
/// hold about `k` points (the local dimension — 2 for a roof or façade, 3 for a tree crown —
/// is estimated from how the occupancy falls when the cell is halved), at most `radius`, and
/// cells must stay addressable by 21-bit coordinates.
fn voxel_width(pts: &[[f64; 3]], lo: [f64; 3], k: usize, radius: f64) -> f64 {
    let o1 = occupancy(pts, lo, radius);
    let o2 = occupancy(pts, lo, radius * 0.5);
    let dim = (o1 / o2.max(1e-9)).log2().clamp(1.0, 3.0);
    let cw = (radius * (k as f64 / o1).powf(1.0 / dim)).min(radius);
    let ext = pts
        .iter()
        .flat_map(|p| (0..3).map(move |d| p[d] - lo[d]))
        .fold(0.0, f64::max);
    cw.max(ext / ((1u64 << 20) as f64)).max(1e-9)
}

/// The table from each cell key to its run of the cell-sorted points (`order` sorted by
/// `cells`, the key per point).
fn cell_runs(order: &[u32], cells: &[u64]) -> CellTable {
    let ncell = 1 + order
        .windows(2)
        .filter(|w| cells[w[0] as usize] != cells[w[1] as usize])
        .count();
    let mut table = CellTable::new(ncell);
    let mut s = 0usize;
    while s < order.len() {
        let c = cells[order[s] as usize];
        let mut e = s + 1;
        while e < order.len() && cells[order[e] as usize] == c {
            e += 1;
        }
        table.insert(c, (s as u32, e as u32));
        s = e;
    }
    table
}

/// The `k` nearest neighbours of every point within `radius`, with a hashed voxel grid.
///
/// The cell width adapts to the data (an occupied cell holds about `k` points, at most
/// `radius` wide). A query whose predecessor (in the callers' spatially coherent order) has
/// `k` neighbours gets a bound on its own `k`-th distance and scans the cells of the box
/// that bound spans; otherwise it scans cubes of
/// cells of growing half-width `L` around its own cell and stops as soon as it holds `k`
/// candidates nearer than the cube's faces (nothing outside the cube can be closer) or the
/// cube covers `radius`.
pub fn knn_voxel(pts: &[[f64; 3]], k: usize, radius: f64) -> Neighbours {
    if pts.is_empty() {
        return Neighbours::rows(0, k);
    }
    let mut lo = [f64::INFINITY; 3];
    for p in pts {
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
        }
    }
    let cw = voxel_width(pts, lo, k, radius);
    let inv = 1.0 / cw;
    let cell_of =
        |p: &[f64; 3]| -> [i64; 3] { std::array::from_fn(|d| ((p[d] - lo[d]) * inv) as i64) };
    let cells: Vec<u64> = pts.iter().map(|p| pack(cell_of(p))).collect();
    let mut order: Vec<u32> = (0..pts.len() as u32).collect();
    order.par_sort_unstable_by_key(|&i| (cells[i as usize], i));
    let sorted: Vec<[f64; 3]> = order.iter().map(|&i| pts[i as usize]).collect();
    let table = cell_runs(&order, &cells);
    drop(cells);
    let r2 = radius * radius;
    let max_l = (radius * inv).ceil() as i64 + 1;
    // Highest cell coordinate per axis: no cell lies beyond it.
    let top: [i64; 3] =
        std::array::from_fn(|d| pts.iter().map(|p| cell_of(p)[d]).max().unwrap_or(0));
    // Offers every point of cell `key` within `b2` (squared) of `p` but point `me`.
    let offer = |cand: &mut Vec<u64>, (a, b): (u32, u32), p: &[f64; 3], me: usize, b2: f64| {
        let (a, b) = (a as usize, b as usize);
        offer_run(cand, &sorted[a..b], &order[a..b], p, me as u32, b2);
    };
    Neighbours::fill(pts.len(), k, |i, prev, cand, cube: &mut CubeCache| {
        let p = &pts[i];
        let c = cell_of(p);
        // As in the 2-D grid: the previous point's k-th distance plus the step between the
        // two bounds this point's k-th; nothing farther is offered. Exact (checked below).
        let b2 = successor_bound(prev, p, i.checked_sub(1).map(|h| &pts[h]), r2);
        // With such a bound the search is a box query: every point within √b2 lies in the
        // cells the box [p − √b2, p + √b2] touches (a hair wider, for rounding), and at least
        // k do, so their k nearest are the answer — no shells, no check.
        if b2 < r2 {
            let b = b2.sqrt() * (1.0 + 1e-9) + 1e-9;
            let c0: [i64; 3] =
                std::array::from_fn(|d| (((p[d] - b - lo[d]) * inv).floor() as i64).max(0));
            let c1: [i64; 3] =
                std::array::from_fn(|d| (((p[d] + b - lo[d]) * inv).floor() as i64).min(top[d]));
            let cells: i64 = (0..3).map(|d| (c1[d] - c0[d] + 1).max(0)).product();
            if cells <= BOX_CELLS {
                for x in c0[0]..=c1[0] {
                    for y in c0[1]..=c1[1] {
                        for z in c0[2]..=c1[2] {
                            if let Some(r) = table.get(pack([x, y, z])) {
                                offer(cand, r, p, i, b2);
                            }
                        }
                    }
                }
                return;
            }
        }
        // Distance from the query to the nearest face of the cube of half-width l cells that
        // has cells beyond it (a hair less, for rounding).
        let u: [f64; 3] = std::array::from_fn(|d| (p[d] - lo[d]) * inv);
        let reach = |l: i64| -> f64 {
            let mut m = f64::INFINITY;
            for d in 0..3 {
                if c[d] - l > 0 {
                    m = m.min(u[d] - (c[d] - l) as f64);
                }
                if c[d] + l < top[d] {
                    m = m.min((c[d] + l + 1) as f64 - u[d]);
                }
            }
            m * cw * (1.0 - 1e-9)
        };
        // The 27 cells around the query's cell are looked up once per cell: consecutive
        // points (canonical order) mostly share a cell.
        let key = pack(c);
        if cube.key != Some(key) {
            cube.key = Some(key);
            cube.ranges.clear();
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(r) = table.get(pack([c[0] + dx, c[1] + dy, c[2] + dz])) {
                            cube.ranges.push(r);
                        }
                    }
                }
            }
        }
        for &r in &cube.ranges {
            offer(cand, r, p, i, b2);
        }
        let mut l = 1i64;
        loop {
            let rl = reach(l);
            if rl * rl >= r2 || l >= max_l {
                break;
            }
            if cand.len() >= k && k > 0 {
                cand.select_nth_unstable(k - 1);
                cand.truncate(k);
                // Strict, in f32: points outside the cube round to at least its reach².
                if dist_of(cand[k - 1]) < (rl * rl) as f32 {
                    break;
                }
            }
            l += 1;
            // Add the shell at Chebyshev distance l.
            for dx in -l..=l {
                for dy in -l..=l {
                    let edge = dx.abs() == l || dy.abs() == l;
                    let dzs: &mut dyn Iterator<Item = i64> = if edge {
                        &mut (-l..=l)
                    } else {
                        &mut [-l, l].into_iter()
                    };
                    for dz in dzs {
                        if let Some(r) = table.get(pack([c[0] + dx, c[1] + dy, c[2] + dz])) {
                            offer(cand, r, p, i, b2);
                        }
                    }
                }
            }
        }
    })
}

/// Bound on the squared `k`-th neighbour distance of `p` from its predecessor `pp` (whose
/// `k`-th squared distance is `prev`): those `k` neighbours, with `pp` itself standing in for
/// `p` if `p` was one of them, lie within √prev + |p − pp|; a hair more for the f32 rounding
/// of `prev`; capped at `r2`, which is also the answer without a predecessor.
#[inline]
fn successor_bound(prev: Option<f32>, p: &[f64; 3], pp: Option<&[f64; 3]>, r2: f64) -> f64 {
    match (prev, pp) {
        (Some(d), Some(pp)) => {
            let step =
                ((pp[0] - p[0]).powi(2) + (pp[1] - p[1]).powi(2) + (pp[2] - p[2]).powi(2)).sqrt();
            (((d as f64).sqrt() + step).powi(2) * (1.0 + 1e-6)).min(r2)
        }
        _ => r2,
    }
}

/// Largest box (in cells) [`knn_voxel`] scans for a query bounded by its predecessor; a
/// larger one takes the shell search around the query's cell instead.
const BOX_CELLS: i64 = 64;

/// The cell ranges of the 3 × 3 × 3 cube around the last query's cell ([`knn_voxel`]).
#[derive(Default)]
struct CubeCache {
    key: Option<u64>,
    ranges: Vec<(u32, u32)>,
}

/// Appends to `cand` every point of a run of a cell-sorted array (`pts`, their indices `ids`)
/// within `b2` (squared) of `p`, except point `me`. Branch-free: every point is written and
/// the length advances only for those that qualify — under the previous point's bound that
/// is close to a coin toss, and a mispredicted branch per point cost more than its distance.
#[inline]
fn offer_run(cand: &mut Vec<u64>, pts: &[[f64; 3]], ids: &[u32], p: &[f64; 3], me: u32, b2: f64) {
    let base = cand.len();
    cand.resize(base + pts.len(), 0);
    let out = &mut cand[base..];
    let mut w = 0;
    for (q, &j) in pts.iter().zip(ids) {
        let d2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2);
        out[w] = packed(d2 as f32, j);
        w += ((d2 <= b2) & (j != me)) as usize;
    }
    cand.truncate(base + w);
}

/// Keeps `best` the `k` smallest [`packed`] candidates offered so far, ascending.
#[inline]
fn keep_nearest(best: &mut Vec<u64>, k: usize, c: u64) {
    if best.len() == k {
        match best.last() {
            Some(&w) if c < w => {
                best.pop();
            }
            _ => return,
        }
    }
    let mut pos = best.len();
    while pos > 0 && c < best[pos - 1] {
        pos -= 1;
    }
    best.insert(pos, c);
}

/// Cell width of [`knn_grid2d`] in units of √(k / density).
const GRID2D_CELL: f64 = 0.7;

/// The `k` nearest neighbours within `radius` (3-D distance) of points on a 2.5-D surface
/// (ground, road), exact, with a grid over xy.
///
/// The cell width is set from the data's density so that a point's 3 × 3 block of cells
/// usually holds its `k` nearest (about three times `k` candidates); a query widens the block
/// ring by ring until its `k`-th candidate is no farther than the block's guaranteed reach
/// (points outside are farther in xy, hence in 3-D) or the block covers `radius`. Queries run
/// in cell order (neighbouring queries read the same cells) and write fixed-width rows, so no
/// list is allocated per point. Same lists as [`knn_kdtree`] (a unit test checks this).
/// Measured on the labelling stage's ground points (demo scene, 5.8 M queries, k = 12,
/// r = 0.35 m): see `scripts/bench_stages.sh` and the README.
pub fn knn_grid2d(pts: &[[f64; 3]], k: usize, radius: f64) -> Neighbours {
    let n = pts.len();
    if n == 0 || k == 0 {
        return Neighbours::rows(n, k);
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in pts {
        for d in 0..2 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    // Density from the occupancy of radius-wide cells: points per occupied cell / cell area.
    let occ = {
        let mut keys: Vec<u64> = pts
            .iter()
            .map(|p| {
                pack([
                    ((p[0] - lo[0]) / radius) as i64,
                    ((p[1] - lo[1]) / radius) as i64,
                    0,
                ])
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        n as f64 / keys.len().max(1) as f64
    };
    let density = occ / (radius * radius);
    let ext = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let cw = (GRID2D_CELL * (k as f64 / density).sqrt())
        .min(radius)
        .max(ext / ((1u64 << 20) as f64))
        .max(1e-9);
    let nx = ((hi[0] - lo[0]) / cw) as usize + 1;
    let ny = ((hi[1] - lo[1]) / cw) as usize + 1;
    // A dense grid when its cells are few against the points (street tiles: ~0.3 cells a
    // point); sparse, far-flung points keep the hashed cells.
    if nx.saturating_mul(ny) <= 4 * n + 65_536 {
        return grid2d_dense(pts, k, radius, lo, cw, [nx, ny]);
    }
    let inv = 1.0 / cw;
    let cell_of = |p: &[f64; 3]| -> [i64; 2] {
        [((p[0] - lo[0]) * inv) as i64, ((p[1] - lo[1]) * inv) as i64]
    };
    let key = |c: [i64; 2]| pack([c[0], c[1], 0]);
    let mut keyed: Vec<(u64, u32)> = pts
        .iter()
        .enumerate()
        .map(|(i, p)| (key(cell_of(p)), i as u32))
        .collect();
    keyed.par_sort_unstable();
    let order: Vec<u32> = keyed.iter().map(|e| e.1).collect();
    let keys: Vec<u64> = keyed.iter().map(|e| e.0).collect();
    drop(keyed);
    let sorted: Vec<[f64; 3]> = order.iter().map(|&i| pts[i as usize]).collect();
    let ncell = 1 + keys.windows(2).filter(|w| w[0] != w[1]).count();
    let mut table = CellTable::new(ncell);
    let mut s = 0usize;
    while s < n {
        let mut e = s + 1;
        while e < n && keys[e] == keys[s] {
            e += 1;
        }
        table.insert(keys[s], (s as u32, e as u32));
        s = e;
    }
    let r2 = radius * radius;
    let max_l = (radius * inv).ceil() as i64 + 1;
    // Rows are computed in cell order (row `q` for the point at sorted position `q`), then
    // moved to point order in place.
    let mut nb = Neighbours::fill(n, k, |q, _, cand, _: &mut ()| {
        let p = &sorted[q];
        let me = order[q];
        let cc = cell_of(p);
        let mut l = 0i64;
        loop {
            for dx in -l..=l {
                let edge = dx.abs() == l;
                let step = if edge || l == 0 { 1 } else { 2 * l };
                let mut dy = -l;
                while dy <= l {
                    if let Some((a, e)) = table.get(key([cc[0] + dx, cc[1] + dy])) {
                        for (t, qp) in sorted[a as usize..e as usize].iter().enumerate() {
                            let d2 = (qp[0] - p[0]).powi(2)
                                + (qp[1] - p[1]).powi(2)
                                + (qp[2] - p[2]).powi(2);
                            let j = order[a as usize + t];
                            if d2 <= r2 && j != me {
                                // Ranked by the f32 distance, as every search here.
                                keep_nearest(cand, k, packed(d2 as f32, j));
                            }
                        }
                    }
                    dy += step;
                }
            }
            let covered = l as f64 * cw;
            if covered >= radius || l >= max_l {
                break;
            }
            // Strict, in f32: points outside the block round to at least covered².
            if cand.len() == k && dist_of(cand[k - 1]) < (covered * covered) as f32 {
                break;
            }
            l += 1;
        }
    });
    drop((sorted, table));
    nb.unpermute(&order);
    nb
}

/// [`knn_grid2d`] on a dense grid of `dims` cells of width `cw` from `lo`: points are
/// counting-sorted into row-major cells, so the 3 × 3 block around a query is three contiguous
/// runs of the sorted array (no hashing). A query first takes that block and stops when its
/// `k`-th candidate is nearer than the block's edge (sides at the grid's border count as
/// infinitely far: nothing lies beyond them) or the block covers `radius`; the rare rest
/// widens ring by ring as the hashed search does.
fn grid2d_dense(
    pts: &[[f64; 3]],
    k: usize,
    radius: f64,
    lo: [f64; 2],
    cw: f64,
    dims: [usize; 2],
) -> Neighbours {
    let n = pts.len();
    let [nx, ny] = dims;
    let inv = 1.0 / cw;
    let cell_xy = |p: &[f64; 3]| -> [usize; 2] {
        [
            (((p[0] - lo[0]) * inv) as usize).min(nx - 1),
            (((p[1] - lo[1]) * inv) as usize).min(ny - 1),
        ]
    };
    // Counting sort by cell; ties keep point order.
    let mut start = vec![0u32; nx * ny + 1];
    let cell: Vec<u32> = pts
        .iter()
        .map(|p| {
            let [cx, cy] = cell_xy(p);
            (cy * nx + cx) as u32
        })
        .collect();
    for &c in &cell {
        start[c as usize + 1] += 1;
    }
    for c in 0..nx * ny {
        start[c + 1] += start[c];
    }
    let mut order = vec![0u32; n];
    {
        let mut next = start.clone();
        for (i, &c) in cell.iter().enumerate() {
            order[next[c as usize] as usize] = i as u32;
            next[c as usize] += 1;
        }
    }
    drop(cell);
    let sorted: Vec<[f64; 3]> = order.iter().map(|&i| pts[i as usize]).collect();
    let r2 = radius * radius;
    let max_l = (radius * inv).ceil() as i64 + 1;
    // Scans cells [x0, x1] of row y, offering every point within `b2` (squared) but the query.
    let scan =
        |cand: &mut Vec<u64>, p: &[f64; 3], me: u32, b2: f64, y: usize, x0: usize, x1: usize| {
            let (a, e) = (start[y * nx + x0] as usize, start[y * nx + x1 + 1] as usize);
            offer_run(cand, &sorted[a..e], &order[a..e], p, me, b2);
        };
    let mut nb = Neighbours::fill(n, k, |q, prev, cand, _: &mut ()| {
        let p = &sorted[q];
        let me = order[q];
        // The previous point's k neighbours (within `prev` of it) all lie within
        // √prev + |p − p'| of this point (the previous point itself among them, standing in
        // for this one if it was on that list): nothing farther can be among this point's k
        // nearest, so the block's scan keeps only what lies within that bound (a hair more,
        // for the f32 rounding of `prev`). Exact: the block result is still checked below.
        let b2 = successor_bound(prev, p, q.checked_sub(1).map(|h| &sorted[h]), r2);
        let [cx, cy] = cell_xy(p);
        let (x0, x1) = (cx.saturating_sub(1), (cx + 1).min(nx - 1));
        for y in cy.saturating_sub(1)..=(cy + 1).min(ny - 1) {
            scan(cand, p, me, b2, y, x0, x1);
        }
        // Distance from the query to the nearest side of the block that has cells beyond it
        // (a hair less, for rounding).
        let u = [(p[0] - lo[0]) * inv, (p[1] - lo[1]) * inv];
        let mut reach = f64::INFINITY;
        for (d, (c, m)) in [(cx, nx), (cy, ny)].into_iter().enumerate() {
            if c >= 2 {
                reach = reach.min(u[d] - (c - 1) as f64);
            }
            if c + 2 < m {
                reach = reach.min((c + 2) as f64 - u[d]);
            }
        }
        let reach = reach * cw * (1.0 - 1e-9);
        if reach * reach >= r2 {
            return;
        }
        if cand.len() >= k {
            cand.select_nth_unstable(k - 1);
            cand.truncate(k);
            if dist_of(cand[k - 1]) < (reach * reach) as f32 {
                return;
            }
        }
        // Rare: widen ring by ring from scratch.
        cand.clear();
        let (cx, cy) = (cx as i64, cy as i64);
        let mut l = 0i64;
        loop {
            for dy in -l..=l {
                let y = cy + dy;
                if y < 0 || y >= ny as i64 {
                    continue;
                }
                if dy.abs() == l {
                    let (x0, x1) = ((cx - l).max(0), (cx + l).min(nx as i64 - 1));
                    if x0 <= x1 {
                        scan(cand, p, me, r2, y as usize, x0 as usize, x1 as usize);
                    }
                } else {
                    for x in [cx - l, cx + l] {
                        if x >= 0 && x < nx as i64 {
                            scan(cand, p, me, r2, y as usize, x as usize, x as usize);
                        }
                    }
                }
            }
            let covered = l as f64 * cw;
            if covered >= radius || l >= max_l {
                break;
            }
            if cand.len() >= k {
                cand.select_nth_unstable(k - 1);
                cand.truncate(k);
                if dist_of(cand[k - 1]) < (covered * covered) as f32 {
                    break;
                }
            }
            l += 1;
        }
    });
    drop(sorted);
    nb.unpermute(&order);
    nb
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg_cloud(n: usize) -> Vec<[f64; 3]> {
        let mut s = 12345u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| [r() * 10.0, r() * 10.0, r() * 0.05])
            .collect()
    }

    #[test]
    fn kdtree_and_grid_agree() {
        let pts = lcg_cloud(5000);
        let a = knn_kdtree(&pts, 12, 0.4);
        let b = knn_voxel(&pts, 12, 0.4);
        assert_eq!(a.len(), b.len());
        for i in 0..a.len() {
            assert_eq!(a.of(i), b.of(i), "point {i}");
        }
    }

    #[test]
    fn kdtree_and_grid2d_agree() {
        let mut pts = lcg_cloud(6000);
        // A kerb: a step of 12 cm along x = 5, and a few points stacked above each other.
        for p in pts.iter_mut() {
            if p[0] > 5.0 {
                p[2] += 0.12;
            }
        }
        for i in 0..50 {
            pts.push([2.0, 2.0, 0.01 * i as f64]);
        }
        // Reference: every pair, ranked by (f32 distance², index). (kiddo's bounded queries
        // keep an arbitrary one of equidistant points at the k-th place, so it is not one.)
        let brute = |i: usize, k: usize, r: f64| -> Vec<u32> {
            let p = pts[i];
            let mut l: Vec<u64> = pts
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(j, q)| {
                    let d2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2);
                    (d2, j as u32)
                })
                .filter(|&(d2, _)| d2 <= r * r)
                .map(|(d2, j)| packed(d2 as f32, j))
                .collect();
            finish(&mut l, k);
            l.into_iter().map(|c| c as u32).collect()
        };
        for (k, r) in [(12, 0.35), (20, 0.2), (5, 1.0)] {
            let b = knn_grid2d(&pts, k, r);
            assert_eq!(b.len(), pts.len());
            for i in (0..pts.len()).step_by(7).chain(5990..pts.len()) {
                assert_eq!(b.of(i), &brute(i, k, r)[..], "k {k} r {r} point {i}");
            }
        }
        assert!(knn_grid2d(&[], 12, 0.3).is_empty());
    }

    #[test]
    fn rows_move_to_point_order_in_place() {
        // Rows computed for points in the order `order` (row q belongs to point order[q]),
        // with cycles of several lengths and fixed points.
        let order: Vec<u32> = vec![3, 0, 1, 2, 4, 6, 5, 9, 7, 8];
        let k = 3;
        let mut nb = Neighbours::rows(order.len(), k);
        for (q, &i) in order.iter().enumerate() {
            nb.cnt[q] = (i % 3) + 1;
            for t in 0..k {
                nb.idx[q * k + t] = 100 * i + t as u32;
                nb.dist2[q * k + t] = i as f32 + 0.1 * t as f32;
            }
        }
        nb.unpermute(&order);
        for i in 0..order.len() {
            let n = (i as u32 % 3 + 1) as usize;
            let want: Vec<u32> = (0..n as u32).map(|t| 100 * i as u32 + t).collect();
            assert_eq!(nb.of(i), &want[..], "point {i}");
            assert_eq!(nb.dist2_of(i)[0], i as f32);
        }
    }

    #[test]
    fn within_is_a_prefix() {
        let pts = lcg_cloud(2000);
        let a = knn_kdtree(&pts, 10, 1.0);
        for i in 0..a.len() {
            let w = a.within(i, 0.09);
            assert!(w.len() <= a.of(i).len());
            for &j in w {
                let d2: f64 = (0..3)
                    .map(|c| (pts[j as usize][c] - pts[i][c]).powi(2))
                    .sum();
                assert!(d2 <= 0.0901);
            }
        }
    }
}
