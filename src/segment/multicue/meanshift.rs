//! Mean-shift segmentation of one cue on the range image (paper §2.4; Comaniciu & Meer 2002):
//! filtering in the joint spatial–range domain, then grouping.
//!
//! Filtering: each pixel starts a window at its own image position and cue value and moves
//! it to the mean of the pixels within `hs` pixels (square) whose value lies within `hr` of
//! the window's value (uniform kernel), until the move is below a hundredth of `hr` and half
//! a pixel, or after `max_iter` moves; the pixel's filtered value is where its window ends.
//! Basins of attraction (`basin`, as in Comaniciu & Meer's faster filter): a pixel not filtered
//! yet — up to `basin` columns to the right of a window's start in its row, or up to `basin`
//! columns either side in the `basin_rows` rows below — that the window passed within a pixel
//! of while its value lay within `basin_hr · hr` of the pixel's, takes that window's end value
//! and starts no window of its own (the default `basin_hr` is ½; 1 is the rule of the
//! high-speedup filter in Comaniciu & Meer's EDISON code, where points within the window's
//! bandwidth during its traversal take its mode, and its medium-speedup filter uses `√½`). Rows are filtered top to bottom in bands of `1 + basin_rows`
//! rows, and a window hands its value on only inside its band; bands are independent, so
//! results do not depend on the thread count. A pixel that starts its own window gets the same
//! value as without basins.
//! Grouping: 4-neighbouring pixels whose filtered values lie within `merge · hr` and that
//! lie on one surface ([`super::cues::same_surface`]) join one segment, so a segment is also
//! connected in 3-D.

use rayon::prelude::*;

use super::cues::Links;
use super::image::RangeImage;

/// Kernel sizes and stopping rule of one cue's mean shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    /// Spatial half-window, pixels.
    pub hs: usize,
    /// Range bandwidth, in the cue's units.
    pub hr: f32,
    /// Most window moves per pixel.
    pub max_iter: usize,
    /// Basins of attraction: pixels up to this many columns to the right of a window's start
    /// (and either side in the rows below, `basin_rows`) may take its end value (0: every
    /// pixel starts its own window, the exact filter).
    pub basin: usize,
    /// Basins also reach this many rows below a window's start (within its band of
    /// `1 + basin_rows` rows, see [`filter`]); 0: the window's own row only.
    pub basin_rows: usize,
    /// Basins: a pixel's value must lie within this share of `hr` of the window's value where
    /// the window passed it (in `(0, 1]`).
    pub basin_hr: f32,
    /// Grouping: filtered values within `merge · hr` join.
    pub merge: f32,
}

/// Whether a squared distance lies within the window's squared bandwidth. Not `d < hr2`: a NaN
/// distance is taken, as it always was (the filter's output stays bit for bit the same).
#[inline(always)]
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn within(d: f32, hr2: f32) -> bool {
    !(d >= hr2)
}

#[inline]
fn d2<const D: usize>(a: &[f32; D], b: &[f32; D]) -> f32 {
    let mut s = 0.0;
    for k in 0..D {
        let d = a[k] - b[k];
        s += d * d;
    }
    s
}

/// The filtered value of every pixel (`values` where `usable` is false). The values of usable
/// pixels must be finite (the cues' are).
pub fn filter<const D: usize>(
    img: &RangeImage,
    values: &[[f32; D]],
    usable: &[bool],
    k: Kernel,
) -> Vec<[f32; D]> {
    let near = (k.basin_hr * k.hr) * (k.basin_hr * k.hr);
    let mut out = values.to_vec();
    let cols = img.cols;
    // What the windows read: the values, and infinity where a pixel is not usable. A window's
    // value is a mean of usable (finite) values, so such a pixel lies infinitely far from it
    // and fails the bandwidth test: the windows take the same pixels without reading
    // `usable`, a load and a test fewer per window pixel.
    debug_assert!(values
        .iter()
        .zip(usable)
        .all(|(v, &u)| !u || v.iter().all(|x| x.is_finite())));
    let seen: Vec<[f32; D]> = values
        .iter()
        .zip(usable)
        .map(|(&v, &u)| if u { v } else { [f32::INFINITY; D] })
        .collect();
    // Bands of `1 + basin_rows` rows: a band's rows are filtered top to bottom, so a window
    // may hand its value to pixels of the rows below it in its band; bands are independent of
    // each other (and run in parallel), so the result does not depend on the thread count.
    let band = 1 + if k.basin > 0 { k.basin_rows } else { 0 };
    let centres = Centres::new(k);
    out.par_chunks_mut(cols * band)
        .enumerate()
        .for_each(|(b, chunk)| {
            let band_rows = chunk.len() / cols;
            // Pixels of this band that start no window: not usable, or they took a window's
            // value (basins). And the window's path.
            let first = b * band * cols;
            let mut done: Vec<bool> = usable[first..first + chunk.len()]
                .iter()
                .map(|&u| !u)
                .collect();
            let mut path: Vec<([f32; D], f32, f32)> = Vec::new();
            for lr in 0..band_rows {
                let r = b * band + lr;
                for c in 0..cols {
                    if done[lr * cols + c] {
                        continue;
                    }
                    let (y, ext) = window(img, &seen, (k, &centres), (r, c), &mut path);
                    chunk[lr * cols + c] = y;
                    if k.basin == 0 {
                        continue;
                    }
                    // Pixels not filtered yet: later in this row, or in the band's rows below
                    // (at most `basin_rows` down), up to `basin` columns either side. Only
                    // those within a pixel of the path's extent can pass: a whole offset
                    // within 1 of a centre offset lies within 1 of its rounding.
                    let last_row = (lr + k.basin_rows).min(band_rows - 1);
                    let rows =
                        lr.max(reach(lr, ext[0] - 1))..(last_row + 1).min(reach(lr, ext[1] + 2));
                    for lr2 in rows {
                        let from = if lr2 == lr {
                            c + 1
                        } else {
                            c.saturating_sub(k.basin)
                        };
                        let cols2 = from.max(reach(c, ext[2] - 1))
                            ..(c + k.basin + 1).min(cols).min(reach(c, ext[3] + 2));
                        for c2 in cols2 {
                            let at = lr2 * cols + c2;
                            let j = first + at;
                            if done[at] {
                                continue;
                            }
                            let (dr, dc) = ((lr2 - lr) as f32, c2 as f32 - c as f32);
                            // From the end back: a pixel that passes mostly passes near the
                            // window's end, so the search stops sooner. Same answer.
                            let passed = path.iter().rev().any(|&(py, pr, pc)| {
                                (dr - pr).abs() <= 1.0
                                    && (dc - pc).abs() <= 1.0
                                    && d2(&values[j], &py) < near
                            });
                            if passed {
                                done[at] = true;
                                chunk[at] = y;
                            }
                        }
                    }
                }
            }
        });
    out
}

/// The mean shift of the window started at pixel `(r, c)` with its own value: where it ends,
/// and the extent of the rounded centre offsets it had (rows min and max, columns min and
/// max). With basins (`k.basin > 0`), `path` is left holding each value and centre offset
/// (pixels, from `(r, c)`) the window had, its end included. `values`: infinite where a
/// pixel is not usable ([`filter`]).
///
/// Not inlined: on its own the window's loop keeps more of its state in registers (the
/// filter 3 % faster, `cargo bench --bench multicue`, 60 m drive).
#[inline(never)]
fn window<const D: usize>(
    img: &RangeImage,
    values: &[[f32; D]],
    (k, centres): (Kernel, &Centres),
    (r, c): (usize, usize),
    path: &mut Vec<([f32; D], f32, f32)>,
) -> ([f32; D], [isize; 4]) {
    let hr2 = k.hr * k.hr;
    let stop_v = (0.01 * k.hr) * (0.01 * k.hr);
    let hs = k.hs as isize;
    let side = 2 * k.hs + 1;
    let (rows, cols) = (img.rows as isize, img.cols as isize);
    let mut y = values[r * img.cols + c];
    // Window centre as an offset from the pixel, in pixels, and its rounding.
    let (mut yr, mut yc) = (0.0f32, 0.0f32);
    let (mut cr, mut cc) = (0isize, 0isize);
    path.clear();
    let mut ext = [isize::MAX, isize::MIN, isize::MAX, isize::MIN];
    for _ in 0..k.max_iter {
        if k.basin > 0 {
            path.push((y, yr, yc));
        }
        ext = extend(ext, (cr, cc));
        let mut acc = [0.0f32; D];
        // Offsets are whole pixels: their sums are kept as integers (exact, as the f32 sums
        // of small integers were) and converted once.
        let (mut sr, mut sc, mut n) = (0isize, 0isize, 0u32);
        let (r0, c0) = (r as isize + cr - hs, c as isize + cc - hs);
        let (r1, c1) = (r0 + 2 * hs, c0 + 2 * hs);
        if r0 >= 0 && c0 >= 0 && r1 < rows && c1 < cols {
            // The window lies inside the image: each of its rows is one run of pixels, read
            // without per-pixel bounds or wrap-around arithmetic. Same pixels in the same
            // order as below, hence the same sums. The default windows' widths are
            // constants here, so their runs are unrolled.
            let at = r0 as usize * img.cols + c0 as usize;
            let win = Window {
                values,
                cols: img.cols,
                hr2,
            };
            let from = (r0 - r as isize, c0 - c as isize);
            (acc, sr, sc, n) = match side {
                3 => win.sums(at, 3, from, &y),
                5 => win.sums(at, 5, from, &y),
                _ => win.sums(at, side, from, &y),
            };
        } else {
            for dr in cr - hs..=cr + hs {
                for dc in cc - hs..=cc + hs {
                    if let Some(j) = img.offset(r, c, dr, dc) {
                        if within(d2(&values[j], &y), hr2) {
                            for q in 0..D {
                                acc[q] += values[j][q];
                            }
                            sr += dr;
                            sc += dc;
                            n += 1;
                        }
                    }
                }
            }
        }
        if n == 0 {
            break;
        }
        let sums = (sr as f32, sc as f32, centres.inv(n));
        let go = shift_window(&mut y, (&mut yr, &mut yc), acc, sums, stop_v);
        // The rounding of the new centre (`yr`, `yc`: the same products).
        (cr, cc) = (centres.of(sr, n), centres.of(sc, n));
        if !go {
            break;
        }
    }
    if k.basin > 0 {
        path.push((y, yr, yc));
        ext = extend(ext, (cr, cc));
    }
    (y, ext)
}

/// `ext` (rows min and max, columns min and max) grown to take `(r, c)`.
#[inline]
fn extend(ext: [isize; 4], (r, c): (isize, isize)) -> [isize; 4] {
    [ext[0].min(r), ext[1].max(r), ext[2].min(c), ext[3].max(c)]
}

/// A window's pixels inside the image, for [`window`] (values infinite where not usable).
struct Window<'a, const D: usize> {
    values: &'a [[f32; D]],
    cols: usize,
    hr2: f32,
}

impl<const D: usize> Window<'_, D> {
    /// Sums of the pixels whose values lie within the bandwidth of `y`, in the square
    /// of `side` pixels whose top-left pixel is `at`, rows top to bottom, each left to
    /// right: values, row and column offsets (`from` is the top-left's offset from the
    /// window's pixel) and count.
    #[inline(always)]
    fn sums(
        &self,
        mut at: usize,
        side: usize,
        (dr0, dc0): (isize, isize),
        y: &[f32; D],
    ) -> ([f32; D], isize, isize, u32) {
        let mut acc = [0.0f32; D];
        let (mut sr, mut sc, mut n) = (0isize, 0isize, 0u32);
        for dr in dr0..dr0 + side as isize {
            for (t, v) in self.values[at..at + side].iter().enumerate() {
                if within(d2(v, y), self.hr2) {
                    for q in 0..D {
                        acc[q] += v[q];
                    }
                    sr += dr;
                    sc += dc0 + t as isize;
                    n += 1;
                }
            }
            at += self.cols;
        }
        (acc, sr, sc, n)
    }
}

/// `at + d`, 0 when negative.
#[inline]
fn reach(at: usize, d: isize) -> usize {
    (at as isize + d).max(0) as usize
}

/// `x.round()` (halves away from zero) for the window offsets (|x| at most a few pixels),
/// without the library call `f32::round` is on x86-64's baseline instruction set: the
/// truncation and its exact remainder decide.
#[inline]
fn round(x: f32) -> isize {
    let t = x as isize;
    let rest = x - t as f32;
    if rest >= 0.5 {
        t + 1
    } else if rest <= -0.5 {
        t - 1
    } else {
        t
    }
}

/// The rounded centre offsets of a window's moves, and the reciprocals of its pixel counts,
/// from tables. A window's new centre offset is `round(s · (1/n))` (f32) of the whole offset
/// sum `s` of the `n` pixels it took; per move, the conversions to and from integers and
/// the division that computed it lay on the path from one move's sums to the next move's
/// pixels (about a seventh of the filter's time, `perf`). The tables hold the same expressions,
/// evaluated once for every count and every sum a window can reach (`max_iter` moves of at
/// most `hs` pixels), so the same values.
struct Centres {
    /// `1/n` for `n` in `0..=side²` (`n = 0` is never read).
    inv: Vec<f32>,
    /// Sums `-reach..=reach` are tabulated; others are computed.
    reach: isize,
    /// Row `n`: `round(s · (1/n))` for `s` in `-reach..=reach`.
    rounded: Vec<i16>,
}

impl Centres {
    fn new(k: Kernel) -> Self {
        let side2 = (2 * k.hs + 1) * (2 * k.hs + 1);
        let inv: Vec<f32> = (0..=side2).map(|n| 1.0 / n as f32).collect();
        // After m moves the centre lies within m·hs of the pixel, so the offsets a move takes
        // lie within (m + 1)·hs and their sum within n times that. The table is bounded (64 Ki
        // entries); sums beyond it are computed.
        let bound = side2
            .saturating_mul(k.max_iter.saturating_add(1))
            .saturating_mul(k.hs);
        let fits = ((1 << 16) / (side2 + 1)).saturating_sub(1) / 2;
        let reach = bound.min(fits) as isize;
        let w = 2 * reach as usize + 1;
        // Row 0 (no pixel taken: the window stops) is never read.
        let mut rounded = vec![0i16; w];
        rounded.reserve(side2 * w);
        for &f in &inv[1..] {
            rounded.extend((-reach..=reach).map(|s| round(s as f32 * f) as i16));
        }
        Centres {
            inv,
            reach,
            rounded,
        }
    }

    /// `1/n` (f32).
    #[inline]
    fn inv(&self, n: u32) -> f32 {
        self.inv[n as usize]
    }

    /// `round(s · (1/n))`, `n` in `1..=side²`.
    #[inline]
    fn of(&self, s: isize, n: u32) -> isize {
        if s.abs() <= self.reach {
            let w = 2 * self.reach + 1;
            self.rounded[(n as isize * w + s + self.reach) as usize] as isize
        } else {
            round(s as f32 * self.inv(n))
        }
    }
}

/// Moves a window to the mean of the pixels it took (value sums `acc`, offset sums `sr`,
/// `sc`, `inv` one over their count, at least one): `y` and its centre `(yr, yc)` are
/// updated. False when the window should stop: it moved less than `stop_v` (squared, in
/// value) and half a pixel.
#[inline]
fn shift_window<const D: usize>(
    y: &mut [f32; D],
    (yr, yc): (&mut f32, &mut f32),
    acc: [f32; D],
    (sr, sc, inv): (f32, f32, f32),
    stop_v: f32,
) -> bool {
    let ny = acc.map(|v| v * inv);
    let (nr, nc) = (sr * inv, sc * inv);
    let moved = d2(&ny, y);
    let spatial = (nr - *yr).powi(2) + (nc - *yc).powi(2);
    *y = ny;
    (*yr, *yc) = (nr, nc);
    !(moved < stop_v && spatial < 0.25)
}

/// Segments of one cue: label per pixel (0 where not usable), numbered 1.. by first pixel.
/// Linked pixels ([`Links`]: neighbours on one surface) whose filtered values lie within
/// `merge · hr` join.
pub fn group<const D: usize>(
    filtered: &[[f32; D]],
    usable: &[bool],
    k: Kernel,
    links: &Links,
) -> (Vec<u32>, u32) {
    let lim = (k.merge * k.hr) * (k.merge * k.hr);
    let joins = |i: usize, j: usize| usable[i] && usable[j] && d2(&filtered[i], &filtered[j]) < lim;
    let mut uf = UnionFind::new(filtered.len());
    // The sets (and so the labels, numbered by first pixel) do not depend on the order of
    // the unions. Along rows first: each row's runs of joined pixels hang on their first
    // pixel without a search; then the runs are joined down and across the seam.
    for &[i, j] in links.row_pairs() {
        let (i, j) = (i as usize, j as usize);
        if joins(i, j) {
            uf.run_on(i, j);
        }
    }
    for &[i, j] in links.other_pairs() {
        let (i, j) = (i as usize, j as usize);
        if joins(i, j) {
            uf.union(i, j);
        }
    }
    uf.labels(usable)
}

/// Union–find over pixels (path halving, union by index so labels are deterministic).
pub(crate) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    pub(crate) fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
        }
    }
    pub(crate) fn find(&mut self, mut i: usize) -> usize {
        while self.parent[i] as usize != i {
            let g = self.parent[self.parent[i] as usize];
            self.parent[i] = g;
            i = g as usize;
        }
        i
    }
    /// Pixel `j` (`j > i`, still alone) joins the run of `i`, a pixel that is a root or
    /// whose parent is one: `j` hangs on that root directly, without a search. Building runs
    /// left to right this way keeps every pixel of a run one step from its first pixel.
    #[inline]
    pub(crate) fn run_on(&mut self, i: usize, j: usize) {
        let root = self.parent[i];
        debug_assert!(i < j && self.parent[j] as usize == j, "{i} -> {j}");
        debug_assert_eq!(self.parent[root as usize], root, "{i}: not a run");
        self.parent[j] = root;
    }
    pub(crate) fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            self.parent[hi] = lo as u32;
        }
    }
    /// Labels 1.. per root in order of first pixel, 0 where `keep` is false. Every pixel of a
    /// set of more than one must be kept (the grouping joins usable pixels only).
    pub(crate) fn labels(&self, keep: &[bool]) -> (Vec<u32>, u32) {
        // No search for roots: a set's root is its smallest pixel (a union hangs the larger
        // root under the smaller, path halving only shortens paths), and every other pixel's
        // parent is smaller than the pixel. In pixel order a root opens its set's label, and
        // each other pixel takes its parent's, which is labelled by then.
        let n = self.parent.len();
        let mut out = vec![0u32; n];
        let mut next = 0;
        for i in 0..n {
            if !keep[i] {
                continue;
            }
            let p = self.parent[i] as usize;
            out[i] = if p == i {
                next += 1;
                next
            } else {
                debug_assert!(p < i && keep[p], "pixel {i}: parent {p}");
                out[p]
            };
        }
        (out, next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::multicue::cues::Jump;

    use crate::segment::multicue::image::tests::{flat_image, STRICT};

    /// The filter as first written: every window pixel through [`RangeImage::offset`] (the
    /// window's move, [`shift_window`], is shared); with basins, every pixel not filtered
    /// yet that the rule names is checked against every value and centre of the window's
    /// path.
    fn filter_reference<const D: usize>(
        img: &RangeImage,
        values: &[[f32; D]],
        usable: &[bool],
        k: Kernel,
    ) -> Vec<[f32; D]> {
        let (hr2, stop_v, hs) = (k.hr * k.hr, (0.01 * k.hr) * (0.01 * k.hr), k.hs as isize);
        let mut out = values.to_vec();
        let mut taken = vec![false; values.len()];
        let band = 1 + if k.basin > 0 { k.basin_rows } else { 0 };
        for i in 0..values.len() {
            let (r, c) = (i / img.cols, i % img.cols);
            if !usable[i] || taken[i] {
                continue;
            }
            let (mut y, mut yr, mut yc) = (values[i], 0.0f32, 0.0f32);
            let mut path = Vec::new();
            for _ in 0..k.max_iter {
                path.push((y, yr, yc));
                let (cr, cc) = (yr.round() as isize, yc.round() as isize);
                let (mut acc, mut sr, mut sc, mut n) = ([0.0f32; D], 0.0f32, 0.0f32, 0u32);
                for dr in cr - hs..=cr + hs {
                    for dc in cc - hs..=cc + hs {
                        let Some(j) = img.offset(r, c, dr, dc) else {
                            continue;
                        };
                        if !usable[j] || d2(&values[j], &y) >= hr2 {
                            continue;
                        }
                        (0..D).for_each(|t| acc[t] += values[j][t]);
                        (sr, sc, n) = (sr + dr as f32, sc + dc as f32, n + 1);
                    }
                }
                if n == 0 {
                    break;
                }
                let inv = 1.0 / n as f32;
                if !shift_window(&mut y, (&mut yr, &mut yc), acc, (sr, sc, inv), stop_v) {
                    break;
                }
            }
            path.push((y, yr, yc));
            out[i] = y;
            if k.basin == 0 {
                continue;
            }
            let near = (k.basin_hr * k.hr) * (k.basin_hr * k.hr);
            let last = (r + k.basin_rows)
                .min(img.rows - 1)
                .min(r - r % band + band - 1);
            for r2 in r..=last {
                for c2 in c.saturating_sub(k.basin)..=(c + k.basin).min(img.cols - 1) {
                    let j = r2 * img.cols + c2;
                    if (r2 == r && c2 <= c) || !usable[j] || taken[j] {
                        continue;
                    }
                    let (dr, dc) = ((r2 - r) as f32, c2 as f32 - c as f32);
                    if path.iter().any(|&(py, pr, pc)| {
                        (dr - pr).abs() <= 1.0
                            && (dc - pc).abs() <= 1.0
                            && d2(&values[j], &py) < near
                    }) {
                        taken[j] = true;
                        out[j] = y;
                    }
                }
            }
        }
        out
    }

    #[test]
    fn round_is_f32_round_for_window_offsets() {
        // Halves, their neighbours one ulp away, and a dense sweep of offsets up to ±40 pixels.
        let mut xs: Vec<f32> = (-80..=80).map(|h| h as f32 * 0.5).collect();
        for &x in xs.clone().iter() {
            xs.extend([x.next_up(), x.next_down()]);
        }
        xs.extend((-400_000..=400_000).map(|i| i as f32 * 1e-4));
        xs.push(f32::NAN);
        for x in xs {
            assert_eq!(round(x), x.round() as isize, "x = {x:e}");
        }
    }

    #[test]
    fn centres_are_the_rounded_products_of_sum_and_reciprocal() {
        // Every count and every sum inside each table and a margin beyond it (computed
        // there), for small and large kernels (a large one's table is cut at 64 Ki entries).
        for (hs, max_iter) in [(1, 5), (1, 1), (2, 5), (3, 20), (32, 5)] {
            let k = Kernel {
                hs,
                hr: 1.0,
                max_iter,
                merge: 0.5,
                basin: 0,
                basin_rows: 0,
                basin_hr: 1.0,
            };
            let c = Centres::new(k);
            let side2 = ((2 * hs + 1) * (2 * hs + 1)) as u32;
            assert!(c.reach > 0, "hs {hs}: no table");
            assert!(c.rounded.len() <= 1 << 16);
            for n in 1..=side2 {
                let inv = 1.0 / n as f32;
                assert_eq!(c.inv(n).to_bits(), inv.to_bits(), "1/{n}");
                for s in -c.reach - 40..=c.reach + 40 {
                    let want = (s as f32 * inv).round() as isize;
                    assert_eq!(c.of(s, n), want, "hs {hs}: round({s} / {n})");
                }
            }
        }
    }

    #[test]
    fn filter_matches_the_reference_bit_for_bit_inside_at_borders_and_across_the_seam() {
        let (rows, cols) = (12, 30);
        let mut rng = crate::rng::Rng(22);
        // Three levels with noise (windows drift towards the levels' centres), a tenth of
        // the pixels unusable.
        let v: Vec<[f32; 3]> = (0..rows * cols)
            .map(|i| {
                let level = [0.0f32, 2.0, 5.0][(i % cols) / 10];
                std::array::from_fn(|d| level + d as f32 + rng.range(-0.6, 0.6) as f32)
            })
            .collect();
        let usable: Vec<bool> = (0..v.len()).map(|_| rng.u() > 0.1).collect();
        for wraps in [false, true] {
            let mut img = flat_image(rows, cols);
            img.wraps = wraps;
            // Window widths 3 and 5 (unrolled) and 9; the exact filter and basins reaching
            // 1 or 3 columns and 0 to 2 rows down.
            let basins = [(0, 0), (1, 0), (3, 1), (2, 2)];
            // Basin shares of the bandwidth: the default 1 and a half.
            let shares = [1.0, 0.5];
            for (hs, (basin, basin_rows), basin_hr) in [1, 2, 4]
                .into_iter()
                .flat_map(|h| basins.map(|b| (h, b)))
                .flat_map(|(h, b)| shares.map(|f| (h, b, f)))
            {
                let k = Kernel {
                    hs,
                    hr: 1.5,
                    max_iter: 6,
                    merge: 0.5,
                    basin,
                    basin_rows,
                    basin_hr,
                };
                let got = filter(&img, &v, &usable, k);
                let want = filter_reference(&img, &v, &usable, k);
                let bits = |a: &[[f32; 3]]| -> Vec<[u32; 3]> {
                    a.iter().map(|x| x.map(f32::to_bits)).collect()
                };
                let at =
                    format!("wraps {wraps}, hs {hs}, basin {basin}/{basin_rows}, share {basin_hr}");
                assert_eq!(bits(&got), bits(&want), "{at}");
                assert!(got != v, "the filter moved nothing: {at}");
            }
        }
    }

    #[test]
    fn basins_hand_on_a_window_value_only_to_pixels_it_passed_with_a_close_value() {
        // Rows of noisy levels with a step of 3 (twice the bandwidth) every 7 columns, the
        // steps one column further in each row (so windows start at every place before one,
        // and a pixel below a window's start may lie across a step from it).
        let (rows, cols) = (14, 40);
        let level = |i: usize| (i % cols + i / cols) / 7;
        let mut rng = crate::rng::Rng(5);
        let v: Vec<[f32; 1]> = (0..rows * cols)
            .map(|i| [3.0 * level(i) as f32 + rng.range(-0.4, 0.4) as f32])
            .collect();
        let usable = vec![true; v.len()];
        let img = flat_image(rows, cols);
        // Two moves: windows end apart, so a value taken from a neighbour shows.
        let kernel = |basin, basin_rows, basin_hr| Kernel {
            hs: 2,
            hr: 1.5,
            max_iter: 2,
            merge: 0.5,
            basin,
            basin_rows,
            basin_hr,
        };
        let exact = filter(&img, &v, &usable, kernel(0, 0, 1.0));
        let cases = [(2, 0), (1, 1), (2, 2)];
        for ((basin, basin_rows), basin_hr) in
            cases.into_iter().flat_map(|b| [1.0, 0.5].map(|f| (b, f)))
        {
            let fast = filter(&img, &v, &usable, kernel(basin, basin_rows, basin_hr));
            let band = 1 + basin_rows;
            let (mut adopted, mut from_above) = (0, 0);
            for i in 0..v.len() {
                if fast[i] == exact[i] {
                    continue;
                }
                // Not its own window's value: that of a window started at most `basin`
                // columns to the left in the same row, or at most `basin` columns either side
                // in a row above in the same band — on the same level (a step is twice the
                // bandwidth away).
                let (r, c) = (i / cols, i % cols);
                let starts = (r - r % band..=r).flat_map(|r2| {
                    let (lo, hi) = if r2 == r {
                        (c.saturating_sub(basin), c.saturating_sub(1))
                    } else {
                        (c.saturating_sub(basin), (c + basin).min(cols - 1))
                    };
                    (lo..=hi).map(move |c2| r2 * cols + c2)
                });
                let from = starts
                    .filter(|&j| j != i)
                    .find(|&j| fast[i] == exact[j])
                    .unwrap_or_else(|| {
                        panic!(
                            "basin {basin}/{basin_rows}, pixel {i}: {:?} is no window's",
                            fast[i]
                        )
                    });
                assert_eq!(
                    level(i),
                    level(from),
                    "basin {basin}/{basin_rows}: pixel {i} took a value across a step"
                );
                adopted += 1;
                from_above += usize::from(from / cols < r);
            }
            // A third or more of the pixels take a neighbour's value instead of starting a
            // window; with rows below in the basin, some take it from the row above.
            assert!(
                adopted > v.len() / 3,
                "basin {basin}/{basin_rows}: only {adopted} of {} pixels adopted",
                v.len()
            );
            assert_eq!(from_above > 0, basin_rows > 0, "{from_above} from above");
            // A different row order (threads) gives the same result.
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            let k = kernel(basin, basin_rows, basin_hr);
            assert_eq!(one.install(|| filter(&img, &v, &usable, k)), fast);
        }
    }

    #[test]
    fn two_noisy_levels_give_two_segments() {
        let (rows, cols) = (20, 40);
        let img = flat_image(rows, cols);
        // Left half ~1.0, right half ~3.0, with deterministic noise of ±0.2.
        let v: Vec<[f32; 1]> = (0..rows * cols)
            .map(|i| {
                let base = if i % cols < cols / 2 { 1.0 } else { 3.0 };
                [base + 0.2 * (((i * 7919) % 13) as f32 / 6.0 - 1.0)]
            })
            .collect();
        let usable = vec![true; v.len()];
        let k = Kernel {
            hs: 3,
            hr: 0.8,
            max_iter: 10,
            merge: 0.5,
            basin: 0,
            basin_rows: 0,
            basin_hr: 1.0,
        };
        let f = filter(&img, &v, &usable, k);
        let jump = STRICT;
        let (lab, n) = group(&f, &usable, k, &Links::new(&img, jump));
        assert_eq!(n, 2, "{lab:?}");
        assert!(lab[..cols / 2].iter().all(|&l| l == 1));
        assert!(lab[cols / 2..cols].iter().all(|&l| l == 2));
        // Filtering brought the noise within a tenth of the step.
        assert!(f
            .iter()
            .all(|x| (x[0] - 1.0).abs() < 0.1 || (x[0] - 3.0).abs() < 0.1));
    }

    #[test]
    fn unusable_pixels_and_range_jumps_split_segments() {
        let (rows, cols) = (4, 10);
        let mut img = flat_image(rows, cols);
        // Column 5 twice as far: a different surface in 3-D although its value matches.
        for r in 0..rows {
            img.range[r * cols + 5] = 20.0;
        }
        let v = vec![[0.0f32]; rows * cols];
        let mut usable = vec![true; rows * cols];
        usable[0] = false;
        let k = exact_3x3();
        let f = filter(&img, &v, &usable, k);
        let (lab, n) = group(&f, &usable, k, &Links::new(&img, STRICT));
        assert_eq!(n, 3);
        assert_eq!(lab[0], 0);
        assert_eq!(lab[1], 1);
        assert_eq!(lab[5], 2);
        assert_eq!(lab[6], 3);
    }

    /// A column without returns (glass, dark paint) cuts a surface with the paper's
    /// 4-neighbours; with `max_gap_px` = 1 the returns on both sides join across it. A range
    /// jump across a missing column still separates, and two missing columns are too wide.
    #[test]
    fn missing_returns_are_bridged_but_range_jumps_are_not() {
        let (rows, cols) = (3, 16);
        let mut img = flat_image(rows, cols);
        for r in 0..rows {
            let row = &mut img.range[r * cols..(r + 1) * cols];
            row[4] = 0.0; // one missing column between 0-3 and 5-7
            row[8] = 0.0; // one missing column, then a surface twice as far
            for v in &mut row[9..12] {
                *v = 20.0;
            }
            row[12] = 0.0; // two missing columns before 14-15 (at 20 m too)
            row[13] = 0.0;
            for v in &mut row[14..] {
                *v = 20.0;
            }
        }
        let usable: Vec<bool> = (0..rows * cols).map(|i| img.valid(i)).collect();
        let v = vec![[0.0f32]; rows * cols];
        let k = exact_3x3();
        let f = filter(&img, &v, &usable, k);
        let run = |max_gap_px| {
            let jump = Jump {
                max_gap_px,
                ..STRICT
            };
            group(&f, &usable, k, &Links::new(&img, jump))
        };
        let (strict, n) = run(0);
        assert_eq!(n, 4, "{strict:?}");
        assert_ne!(strict[3], strict[5]);
        let (bridged, n) = run(1);
        assert_eq!(n, 3, "{bridged:?}");
        assert_eq!(bridged[3], bridged[5]);
        assert_eq!(bridged[0], bridged[7]);
        assert_ne!(bridged[7], bridged[9], "range jump across the gap");
        assert_ne!(bridged[11], bridged[14], "two missing columns");
        assert_eq!((bridged[4], bridged[8], bridged[12]), (0, 0, 0));
        for r in 1..rows {
            assert_eq!(bridged[r * cols + 5], bridged[5]);
        }
    }

    /// The exact filter (no basins) with a 3 × 3 window, bandwidth 1, three moves at most,
    /// filtered values within 0.5 joining.
    fn exact_3x3() -> Kernel {
        Kernel {
            hs: 1,
            hr: 1.0,
            max_iter: 3,
            merge: 0.5,
            basin: 0,
            basin_rows: 0,
            basin_hr: 1.0,
        }
    }

    /// The grouping (runs along rows, then unions down and across the seam) gives the
    /// connected components of the linked pixel pairs whose filtered values join, numbered by
    /// first pixel: a flood fill over every pixel's four links says the same, on images with
    /// holes, range steps, unusable pixels and rows joined across the seam.
    #[test]
    fn grouping_is_the_components_of_the_joining_links() {
        let mut rng = crate::rng::Rng(2212);
        let (mut across_seam, mut joined) = (0, 0);
        for round in 0..40 {
            let (rows, cols) = (2 + round % 9, 3 + (rng.u() * 40.0) as usize);
            let mut img = flat_image(rows, cols);
            img.wraps = round % 4 != 0;
            for r in img.range.iter_mut() {
                let u = rng.u();
                *r = if u < 0.15 {
                    0.0
                } else if u < 0.25 {
                    20.0
                } else {
                    10.0
                };
            }
            let usable: Vec<bool> = (0..img.len())
                .map(|i| img.valid(i) && rng.u() < 0.9)
                .collect();
            let f: Vec<[f32; 1]> = (0..img.len())
                .map(|_| [(rng.u() * 3.0).floor() as f32 + 0.1 * rng.u() as f32])
                .collect();
            let k = exact_3x3();
            for max_gap_px in [0, 1, 2] {
                let links = Links::new(
                    &img,
                    Jump {
                        max_gap_px,
                        ..STRICT
                    },
                );
                let got = group(&f, &usable, k, &links);
                let joins = |i: usize, j: usize| usable[i] && usable[j] && d2(&f[i], &f[j]) < 0.25;
                let (mut want, mut next) = (vec![0u32; img.len()], 0);
                for start in 0..img.len() {
                    if !usable[start] || want[start] != 0 {
                        continue;
                    }
                    next += 1;
                    want[start] = next;
                    let mut stack = vec![start];
                    while let Some(i) = stack.pop() {
                        for (j, _) in links.around(i).into_iter().flatten() {
                            let j = j as usize;
                            if want[j] == 0 && joins(i, j) {
                                want[j] = next;
                                stack.push(j);
                            }
                        }
                    }
                }
                assert_eq!(got, (want.clone(), next), "round {round}, gap {max_gap_px}");
                joined += want.iter().filter(|&&l| l > 0).count() - next as usize;
                across_seam += (0..rows)
                    .filter(|&r| {
                        let (a, b) = (r * cols, r * cols + cols - 1);
                        want[a] > 0
                            && want[a] == want[b]
                            && links.around(b)[0].is_some_and(|(j, _)| j as usize == a)
                            && joins(b, a)
                    })
                    .count();
            }
        }
        assert!(
            joined > 1000 && across_seam > 20,
            "{joined} joined, {across_seam} across"
        );
    }

    /// Labels without a search for roots are those of searching each kept pixel's root and
    /// numbering roots by first pixel, after random unions among kept pixels (as the grouping
    /// makes them: forward pairs, any order of sizes).
    #[test]
    fn labels_by_parent_are_labels_by_root() {
        let mut rng = crate::rng::Rng(22);
        for round in 0..50 {
            let n = 1 + (rng.u() * 400.0) as usize;
            let keep: Vec<bool> = (0..n).map(|_| rng.u() < 0.7).collect();
            let kept: Vec<usize> = (0..n).filter(|&i| keep[i]).collect();
            let mut uf = UnionFind::new(n);
            for _ in 0..(rng.u() * 2.0 * n as f64) as usize {
                if kept.len() < 2 {
                    break;
                }
                let a = kept[(rng.u() * kept.len() as f64) as usize];
                let b = kept[(rng.u() * kept.len() as f64) as usize];
                uf.union(a.min(b), a.max(b));
            }
            let (got, count) = uf.labels(&keep);
            let (mut id, mut want, mut next) = (vec![0u32; n], vec![0u32; n], 0);
            for i in 0..n {
                if keep[i] {
                    let r = uf.find(i);
                    if id[r] == 0 {
                        next += 1;
                        id[r] = next;
                    }
                    want[i] = id[r];
                }
            }
            assert_eq!((got, count), (want, next), "round {round}");
        }
    }
}
