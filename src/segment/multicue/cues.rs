//! The cues segmented on the range image (paper §2.3): range, surface normals, colour.
//!
//! Normals come from differences between neighbouring pixels (eq. 3) of the range image after
//! an adaptive Gaussian smoothing whose window is a fixed physical size `D` translated into
//! pixels by the range: `d(ρ) ≈ D / (ρ Δ)` (eq. 4), separately along rows and columns (a
//! spinning sensor's rings are several times farther apart than its columns). Smoothing and
//! differences stay on one surface ([`same_surface`]).

use super::image::RangeImage;

/// Largest half-window of the smoothing, pixels (near the sensor `D / ρΔ` grows without
/// bound).
const MAX_HALF: usize = 6;

/// Whether two returns at ranges `a` and `b`, whose beams are `alpha` radians apart, lie on
/// one surface (Bogoslavskyi & Stachniss, IROS 2016): the angle β between the farther beam
/// and the line joining the two points, `tan β = d₂ sin α / (d₁ − d₂ cos α)`, is at least θ
/// (`tan_theta`). A range step reads as a break in proportion to the beams' spacing, so
/// the test holds at every range and for rings and columns of different spacing; surfaces
/// seen at a grazing angle below θ (far ground) break too.
#[inline]
pub fn same_surface(a: f32, b: f32, alpha: f32, tan_theta: f32) -> bool {
    same_surface_cs(a, b, [alpha.cos(), alpha.sin()], tan_theta)
}

/// [`same_surface`] with the cosine and sine of the beams' angle given.
#[inline]
fn same_surface_cs(a: f32, b: f32, [cos, sin]: [f32; 2], tan_theta: f32) -> bool {
    // The farther and the nearer return without a branch: which of two neighbours is
    // farther is a coin toss on a smooth surface (that branch was half of the normals'
    // simulated mispredicts). For finite ranges, as the image's are, the same pair as
    // choosing by `a >= b`. Written as the selects x86's `maxss` / `minss` compute, not as
    // `f32::max` / `min`, whose NaN rule costs a mask and a blend per pair.
    let d1 = if a > b { a } else { b };
    let d2 = if a < b { a } else { b };
    let den = d1 - d2 * cos;
    den <= 0.0 || d2 * sin >= tan_theta * den
}

/// The surface test of [`same_surface`] between pixels of one image, its trigonometry
/// computed once: the cosine and sine of the angle between beams up to `reach` rows and
/// columns apart, from a table (the same values the test computes per pair, so the same
/// answers). Per pixel pair, `cos` and `sin` had been a tenth of a scan's segmentation time
/// (`perf` of `benches/multicue.rs`).
pub struct SurfaceTest {
    tan_theta: f32,
    reach: isize,
    cs: Vec<[f32; 2]>,
    /// The table's column `dc = 0` (rows `-reach..=reach`), contiguous for the column pass
    /// of the normals' smoothing.
    column: Vec<[f32; 2]>,
    row_step: f32,
    col_step: f32,
}

impl SurfaceTest {
    /// The test for `img`'s beam spacing with threshold `tan_theta`, tabulated up to `reach`.
    pub fn new(img: &RangeImage, tan_theta: f32, reach: usize) -> Self {
        let reach = reach as isize;
        let mut cs = Vec::with_capacity(((2 * reach + 1) * (2 * reach + 1)) as usize);
        for dr in -reach..=reach {
            for dc in -reach..=reach {
                let alpha = img.step(dr, dc);
                cs.push([alpha.cos(), alpha.sin()]);
            }
        }
        let w = (2 * reach + 1) as usize;
        let column = cs.iter().skip(reach as usize).step_by(w).copied().collect();
        SurfaceTest {
            tan_theta,
            reach,
            cs,
            column,
            row_step: img.row_step,
            col_step: img.col_step,
        }
    }

    /// The table's cosines and sines for `dr` rows and `-half..=half` columns apart, when it
    /// reaches that far.
    #[inline]
    fn row(&self, dr: isize, half: isize) -> Option<&[[f32; 2]]> {
        if dr.abs() > self.reach || half > self.reach {
            return None;
        }
        let w = 2 * self.reach + 1;
        let at = ((dr + self.reach) * w + self.reach - half) as usize;
        Some(&self.cs[at..=at + 2 * half as usize])
    }

    /// The table's cosines and sines for `-half..=half` rows and no column apart, when it
    /// reaches that far.
    #[inline]
    fn column(&self, half: isize) -> Option<&[[f32; 2]]> {
        if half > self.reach {
            return None;
        }
        let at = (self.reach - half) as usize;
        Some(&self.column[at..=at + 2 * half as usize])
    }

    /// Whether returns at ranges `a` and `b`, `dr` rows and `dc` columns apart, lie on one
    /// surface ([`same_surface`]).
    #[inline]
    pub fn holds(&self, a: f32, b: f32, dr: isize, dc: isize) -> bool {
        same_surface_cs(a, b, self.cos_sin(dr, dc), self.tan_theta)
    }

    /// The cosine and sine of the angle between beams `dr` rows and `dc` columns apart: from
    /// the table where it reaches, else computed.
    #[inline]
    fn cos_sin(&self, dr: isize, dc: isize) -> [f32; 2] {
        let w = 2 * self.reach + 1;
        if dr.abs() <= self.reach && dc.abs() <= self.reach {
            self.cs[((dr + self.reach) * w + dc + self.reach) as usize]
        } else {
            let (x, y) = (dr as f32 * self.row_step, dc as f32 * self.col_step);
            let alpha = (x * x + y * y).sqrt();
            [alpha.cos(), alpha.sin()]
        }
    }
}

/// Surface connectivity between neighbouring pixels ([`same_surface`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jump {
    /// tan θ: the smallest angle between a beam and the line to its neighbour's return.
    pub tan_theta: f32,
    /// Pixels without a return that neighbouring returns may lie across
    /// ([`RangeImage::across`]).
    pub max_gap_px: usize,
}

/// A neighbour link: the pixel and how many steps away it lies (1: adjacent; more across
/// pixels without a return, [`RangeImage::across`]).
pub type Link = Option<(u32, u8)>;

/// The surface connectivity of one image, computed once and shared by everything that walks
/// it (the normals' differences, each cue's grouping, the integration's regrouping): for each
/// pixel with a return, its neighbour in each of the four directions
/// ([`RangeImage::across`], across at most `max_gap_px` pixels without a return) when the two
/// lie on one surface ([`SurfaceTest`]), else none. Each cue used to repeat the search and the
/// test for every pixel pair.
pub struct Links {
    /// The surface test, tabulated far enough for the normals' smoothing too.
    pub test: SurfaceTest,
    /// Per pixel: right, left, down, up (the order the regrouping walks them), each packed
    /// ([`pack`]): half the memory of four [`Link`]s, which every pixel's links are written
    /// to and read from.
    around: Vec<[u32; 4]>,
    /// Every link to a right neighbour that does not cross the seam, as the pair of pixels,
    /// in pixel order: the later pixel's only link from its left within the row.
    row_pairs: Vec<[u32; 2]>,
    /// Every other link once: down, and right across the seam; in pixel order.
    other_pairs: Vec<[u32; 2]>,
}

impl Links {
    /// The links of `img` under `jump`.
    pub fn new(img: &RangeImage, jump: Jump) -> Self {
        let test = SurfaceTest::new(img, jump.tan_theta, MAX_HALF.max(jump.max_gap_px + 1));
        let (rows, cols) = (img.rows, img.cols);
        let reach = jump.max_gap_px + 1;
        // The table's cosines and sines for 1..=reach steps right and down.
        let steps = |dr: isize, dc: isize| -> Vec<[f32; 2]> {
            (1..=reach as isize)
                .map(|k| test.cos_sin(k * dr, k * dc))
                .collect()
        };
        let (right_cs, down_cs) = (steps(0, 1), steps(1, 0));
        // Images hold at most 2²⁸ pixels (`RangeImage`'s constructors refuse larger ones) and
        // `max_gap_px` is at most 8 (`MulticueParams::validate`): links pack into 32 bits.
        assert!(
            img.len() <= super::image::MAX_PIXELS && reach < 16,
            "neighbour links: {} pixels, {reach} steps: too many to pack",
            img.len()
        );
        let mut around = vec![[NO_LINK; 4]; img.len()];
        let mut row_pairs = Vec::with_capacity(img.valid_count());
        let mut other_pairs = Vec::with_capacity(img.valid_count());
        for r in 0..rows {
            for c in 0..cols {
                let i = r * cols + c;
                if !img.valid(i) {
                    continue;
                }
                let rho = img.range[i];
                // Right and down; the link back (left, up) is the same pair: the first pixel
                // with a return after `i` has `i` as its first one before, at the same
                // distance, and the test is symmetric. Away from the image's last columns
                // and rows the search needs neither the seam nor the image's end
                // (`RangeImage::across` handles those): the same pixels, found directly.
                let right = if c + reach < cols {
                    (1..=reach).find(|&k| img.valid(i + k)).map(|k| (i + k, k))
                } else {
                    img.across(r, c, 0, 1, jump.max_gap_px)
                        .map(|(j, k)| (j, k as usize))
                };
                if let Some((j, k)) = right {
                    if same_surface_cs(rho, img.range[j], right_cs[k - 1], test.tan_theta) {
                        around[i][0] = pack(j, k);
                        around[j][1] = pack(i, k);
                        if j > i {
                            row_pairs.push([i as u32, j as u32]);
                        } else {
                            other_pairs.push([i as u32, j as u32]);
                        }
                    }
                }
                let down = if r + reach < rows {
                    (1..=reach)
                        .find(|&k| img.valid(i + k * cols))
                        .map(|k| (i + k * cols, k))
                } else {
                    img.across(r, c, 1, 0, jump.max_gap_px)
                        .map(|(j, k)| (j, k as usize))
                };
                if let Some((j, k)) = down {
                    if same_surface_cs(rho, img.range[j], down_cs[k - 1], test.tan_theta) {
                        around[i][2] = pack(j, k);
                        around[j][3] = pack(i, k);
                        other_pairs.push([i as u32, j as u32]);
                    }
                }
            }
        }
        Links {
            test,
            around,
            row_pairs,
            other_pairs,
        }
    }

    /// Every link along a row once, as `[i, j]`: `j` is `i`'s right neighbour, `j > i` (the
    /// links across the seam are in [`Links::other_pairs`]), and no other of these pairs has
    /// `j` second (its down and seam links may). In pixel order. Each cue's grouping tests these pairs without visiting pixels
    /// that have no return or copying their four links.
    #[inline]
    pub fn row_pairs(&self) -> &[[u32; 2]] {
        &self.row_pairs
    }

    /// Every other link once, as `[i, j]` with `j` the right (across the seam) or down
    /// neighbour of `i`, in pixel order.
    #[inline]
    pub fn other_pairs(&self) -> &[[u32; 2]] {
        &self.other_pairs
    }

    /// The linked neighbours of pixel `i`: right, left, down, up.
    #[inline]
    pub fn around(&self, i: usize) -> [Link; 4] {
        self.around[i].map(|l| (l != NO_LINK).then_some((l >> 4, (l & 15) as u8)))
    }
}

/// A packed link: the pixel in the upper 28 bits, the steps in the lower 4.
#[inline]
fn pack(j: usize, k: usize) -> u32 {
    (j as u32) << 4 | k as u32
}

/// No link, packed: no link has 0 steps. (An array of them is zeroed memory.)
const NO_LINK: u32 = 0;

/// Unit normals per pixel (zero where none can be computed), oriented towards the sensor.
/// `window_m` is the paper's `D`; `links` hold the surface test ([`same_surface`]).
pub fn normals(img: &RangeImage, window_m: f32, links: &Links) -> Vec<[f32; 3]> {
    let smooth = smoothed(img, window_m, &links.test);
    let mut out = vec![[0.0f32; 3]; img.len()];
    // The adjacent neighbour on the same surface, if linked.
    let adjacent = |l: Link| l.filter(|&(_, k)| k == 1).map(|(j, _)| j as usize);
    for (i, o) in out.iter_mut().enumerate() {
        if !img.valid(i) {
            continue;
        }
        let [right, left, down, up] = links.around(i);
        // Central difference, else one-sided.
        let diff = |fwd: Link, back: Link| -> Option<[f32; 3]> {
            let (a, b) = match (adjacent(fwd), adjacent(back)) {
                (Some(a), Some(b)) => (a, b),
                (Some(a), None) => (a, i),
                (None, Some(b)) => (i, b),
                (None, None) => return None,
            };
            Some(sub(smooth[a], smooth[b]))
        };
        if let (Some(v1), Some(v2)) = (diff(right, left), diff(down, up)) {
            let n = cross(v1, v2);
            let len = dot(n, n).sqrt();
            if len > 1e-12 {
                let p = img.xyz[i];
                let s = if dot(n, p) > 0.0 { -1.0 } else { 1.0 };
                *o = n.map(|v| s * v / len);
            }
        }
    }
    out
}

/// The range image's points after the adaptive Gaussian smoothing (σ = half the window),
/// applied as the Gaussian separates: along each row over `2 hc + 1` columns, then along each
/// column of that result over `2 hr + 1` rows, the half-windows `hc`, `hr` from the pixel's
/// own range (eq. 4). In both passes a neighbour counts only when it has a return on the
/// pixel's surface ([`SurfaceTest`], against the pixel's own range), and each pass divides by
/// the weights it took. Where every neighbour counts this is the full 2-D kernel; it costs
/// `2 hc + 2 hr + 2` pixels instead of `(2 hc + 1)(2 hr + 1)` — near the sensor, where the
/// windows reach 13 × 13 pixels, 26 instead of 169. `test` must reach [`MAX_HALF`]
/// ([`Links::new`] tabulates that far).
///
/// Both passes smooth [`LANES`] neighbouring pixels of a row side by side ([`Block`]), each
/// with its own half-window; where a block's windows would leave the image or wrap around
/// it, its pixels are smoothed one at a time. Either way a pixel's sums take the same
/// neighbours in the same order, so the result is the same to the bit.
fn smoothed(img: &RangeImage, window_m: f32, test: &SurfaceTest) -> Vec<[f32; 3]> {
    if window_m <= 0.0 {
        return img.xyz.clone();
    }
    // A pixel's range and half-window along beams `step` apart; none without a return or
    // with a window of the pixel alone.
    let half = |i: usize, step: f32| -> Option<(f32, usize)> {
        let rho = img.range[i];
        if rho <= 0.0 {
            return None;
        }
        let d = window_m / (rho * step).max(1e-9);
        let h = ((d * 0.5) as usize).min(MAX_HALF);
        (h > 0).then_some((rho, h))
    };
    let weights = Weights::new();
    let (rows, cols) = (img.rows, img.cols);
    let tan = test.tan_theta;
    // The points by coordinate, zero without a return: a block reads its neighbours as runs,
    // and a neighbour that does not count (weight zero) adds exactly nothing.
    let mut points: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; img.len()]);
    for (i, p) in img.xyz.iter().enumerate() {
        if img.valid(i) {
            for (a, &v) in points.iter_mut().zip(p) {
                a[i] = v;
            }
        }
    }
    // Pass 1: along rows.
    let mut along = points.clone();
    for r in 0..rows {
        for c0 in (0..cols).step_by(LANES) {
            let i0 = r * cols + c0;
            let block = Block::new(i0, cols - c0, |i| half(i, img.col_step));
            let hmax = block.hmax;
            match test.row(0, hmax as isize) {
                // The block's windows lie inside the row: each tap is a run of pixels.
                Some(cs) if block.full && c0 >= hmax && c0 + LANES + hmax <= cols => {
                    let sums = block.sums(&weights, tan, &img.range, &points, |t| {
                        Some((cs[t], i0 + t - hmax))
                    });
                    block.store(&sums, &mut along);
                }
                _ => {
                    for (k, i) in (i0..).enumerate().take(block.len) {
                        let Some((rho, h)) = block.lane(k) else {
                            continue;
                        };
                        let (mut acc, mut wsum) = ([0.0f32; 3], 0.0f32);
                        let hc = h as isize;
                        for (dc, &w) in (-hc..=hc).zip(weights.kernel(h)) {
                            let Some(j) = img.offset(r, c0 + k, 0, dc) else {
                                continue;
                            };
                            if img.valid(j) && test.holds(rho, img.range[j], 0, dc) {
                                add(&mut acc, &mut wsum, w, img.xyz[j]);
                            }
                        }
                        for (a, v) in along.iter_mut().zip(acc) {
                            a[i] = v / wsum;
                        }
                    }
                }
            }
        }
    }
    // Pass 2: along columns, of the rows' result. Rows do not wrap; taps outside the image
    // are left out.
    let mut smooth = along.clone();
    for r in 0..rows {
        for c0 in (0..cols).step_by(LANES) {
            let i0 = r * cols + c0;
            let block = Block::new(i0, cols - c0, |i| half(i, img.row_step));
            let hmax = block.hmax;
            match test.column(hmax as isize) {
                Some(cs) if block.full => {
                    let sums = block.sums(&weights, tan, &img.range, &along, |t| {
                        let rr = (r + t).checked_sub(hmax).filter(|&rr| rr < rows)?;
                        Some((cs[t], rr * cols + c0))
                    });
                    block.store(&sums, &mut smooth);
                }
                _ => {
                    for (k, i) in (i0..).enumerate().take(block.len) {
                        let Some((rho, h)) = block.lane(k) else {
                            continue;
                        };
                        let (mut acc, mut wsum) = ([0.0f32; 3], 0.0f32);
                        for (dr, &w) in (-(h as isize)..=h as isize).zip(weights.kernel(h)) {
                            let rr = r as isize + dr;
                            if rr < 0 || rr >= rows as isize {
                                continue;
                            }
                            let j = (i as isize + dr * cols as isize) as usize;
                            let rj = img.range[j];
                            if rj > 0.0 && test.holds(rho, rj, dr, 0) {
                                let p = [along[0][j], along[1][j], along[2][j]];
                                add(&mut acc, &mut wsum, w, p);
                            }
                        }
                        for (a, v) in smooth.iter_mut().zip(acc) {
                            a[i] = v / wsum;
                        }
                    }
                }
            }
        }
    }
    // Pixels without a return keep their point, as they always did.
    let mut out = img.xyz.clone();
    for (i, o) in out.iter_mut().enumerate() {
        if img.valid(i) {
            *o = [smooth[0][i], smooth[1][i], smooth[2][i]];
        }
    }
    out
}

/// Pixels of a row the smoothing takes side by side ([`Block`]).
const LANES: usize = 8;

/// The smoothing's Gaussian weights for every half-window `h` in `0..=MAX_HALF`, at offsets
/// `-MAX_HALF..=MAX_HALF` (zero beyond `h`).
struct Weights(Vec<f32>);

impl Weights {
    const SIDE: usize = 2 * MAX_HALF + 1;

    fn new() -> Self {
        Weights(
            (0..=MAX_HALF)
                .flat_map(|h| {
                    let s = (h as f32).max(0.5);
                    (-(MAX_HALF as isize)..=MAX_HALF as isize).map(move |d| {
                        let f = d as f32 / s;
                        if d.unsigned_abs() <= h {
                            (-0.5 * f * f).exp()
                        } else {
                            0.0
                        }
                    })
                })
                .collect(),
        )
    }

    /// The weights of half-window `h`, offsets `-h..=h`.
    fn kernel(&self, h: usize) -> &[f32] {
        &self.0[h * Self::SIDE + MAX_HALF - h..=h * Self::SIDE + MAX_HALF + h]
    }
}

/// Up to [`LANES`] neighbouring pixels of a row, smoothed side by side: each pixel's range and
/// half-window (0: the pixel is not smoothed).
struct Block {
    rho: [f32; LANES],
    h: [usize; LANES],
    /// The largest half-window.
    hmax: usize,
    /// The first pixel.
    i0: usize,
    /// Pixels in the block; `full` when [`LANES`].
    len: usize,
    full: bool,
}

impl Block {
    /// The block of pixels from `i0`, at most `room` of them; `half` as in [`smoothed`].
    fn new(i0: usize, room: usize, half: impl Fn(usize) -> Option<(f32, usize)>) -> Self {
        let len = room.min(LANES);
        let (mut rho, mut h) = ([0.0f32; LANES], [0usize; LANES]);
        for k in 0..len {
            if let Some((p, hk)) = half(i0 + k) {
                (rho[k], h[k]) = (p, hk);
            }
        }
        Block {
            rho,
            h,
            hmax: h.iter().copied().max().unwrap_or(0),
            i0,
            len,
            full: len == LANES,
        }
    }

    /// Pixel `k`'s range and half-window, if it is smoothed.
    fn lane(&self, k: usize) -> Option<(f32, usize)> {
        (self.h[k] > 0).then_some((self.rho[k], self.h[k]))
    }

    /// A full block's weighted sums (x, y, z and the weights) over the taps `t` in
    /// `0..=2 hmax` (offset `t - hmax`): `tap(t)` gives the tap's cosine and sine and the
    /// first of its [`LANES`] neighbours in `range` and `p`, none where the tap lies outside
    /// the image. Per pixel, the terms of its own window in the order of the one-at-a-time
    /// sums; the taps beyond its half-window weigh zero and add exactly nothing (the points
    /// are finite, and the sums never -0).
    #[inline]
    fn sums(
        &self,
        weights: &Weights,
        tan: f32,
        range: &[f32],
        p: &[Vec<f32>; 3],
        tap: impl Fn(usize) -> Option<([f32; 2], usize)>,
    ) -> [[f32; LANES]; 4] {
        let mut acc = [[0.0f32; LANES]; 4];
        let from = |h: usize| h * Weights::SIDE + MAX_HALF - self.hmax;
        let base: [usize; LANES] = self.h.map(from);
        for t in 0..=2 * self.hmax {
            let Some(([cos, sin], j)) = tap(t) else {
                continue;
            };
            let w: [f32; LANES] = std::array::from_fn(|k| weights.0[base[k] + t]);
            let rj = &range[j..j + LANES];
            let (x, y, z) = (
                &p[0][j..j + LANES],
                &p[1][j..j + LANES],
                &p[2][j..j + LANES],
            );
            for k in 0..LANES {
                let (a, b) = (self.rho[k], rj[k]);
                // `same_surface_cs`, lane by lane.
                let d1 = if a > b { a } else { b };
                let d2 = if a < b { a } else { b };
                let den = d1 - d2 * cos;
                let ok = (b > 0.0) & ((den <= 0.0) | (d2 * sin >= tan * den));
                let m = if ok { w[k] } else { 0.0 };
                acc[0][k] += m * x[k];
                acc[1][k] += m * y[k];
                acc[2][k] += m * z[k];
                acc[3][k] += m;
            }
        }
        acc
    }

    /// The smoothed points of the block's smoothed pixels into `out`.
    fn store(&self, sums: &[[f32; LANES]; 4], out: &mut [Vec<f32>; 3]) {
        for k in 0..LANES {
            if self.h[k] > 0 {
                for (o, s) in out.iter_mut().zip(sums) {
                    o[self.i0 + k] = s[k] / sums[3][k];
                }
            }
        }
    }
}

/// `acc += w p`, `wsum += w`: one neighbour's share of a weighted mean.
#[inline(always)]
fn add(acc: &mut [f32; 3], wsum: &mut f32, w: f32, p: [f32; 3]) {
    for (a, v) in acc.iter_mut().zip(p) {
        *a += w * v;
    }
    *wsum += w;
}

#[inline]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::super::image::tests::plane_and_wall;
    use super::*;

    #[test]
    fn surface_test_orders_the_ranges_as_a_comparison_would() {
        // The test as first written: the farther return chosen by a comparison.
        let by_comparison = |a: f32, b: f32, [cos, sin]: [f32; 2], t: f32| {
            let (d1, d2) = if a >= b { (a, b) } else { (b, a) };
            let den = d1 - d2 * cos;
            den <= 0.0 || d2 * sin >= t * den
        };
        let mut rng = crate::rng::Rng(7);
        let t = 3f32.to_radians().tan();
        let mut held = [0usize; 2];
        for i in 0..200_000 {
            let a = 0.5 + 40.0 * rng.u() as f32;
            // Equal ranges, a range step, and nearly the same range.
            let b = match i % 3 {
                0 => a,
                1 => 0.5 + 40.0 * rng.u() as f32,
                _ => a * (1.0 + 0.01 * (rng.u() as f32 - 0.5)),
            };
            let alpha = 0.001 + 0.05 * rng.u() as f32;
            let cs = [alpha.cos(), alpha.sin()];
            let want = by_comparison(a, b, cs, t);
            assert_eq!(same_surface_cs(a, b, cs, t), want, "{a} {b} {alpha}");
            assert_eq!(same_surface_cs(b, a, cs, t), want, "{b} {a} {alpha}");
            held[want as usize] += 1;
        }
        // Both answers were exercised.
        assert!(held[0] > 10_000 && held[1] > 10_000, "{held:?}");
    }

    #[test]
    fn plane_and_wall_normals() {
        let (rows, cols) = (16, 360);
        let pts = plane_and_wall(rows, cols);
        let img =
            RangeImage::organised(rows, cols, &pts, None, super::super::image::Order::RowMajor)
                .unwrap();
        let jump = Jump {
            tan_theta: 3f32.to_radians().tan(),
            max_gap_px: 0,
        };
        let n = normals(&img, 0.3, &Links::new(&img, jump));
        // [good, all] for ground and wall pixels; a pixel next to where the two surfaces
        // meet may average both. Ground seen at less than the 3° of the surface test (beyond
        // ~38 m from a sensor 2 m up) has no neighbouring ring on its surface.
        let (mut ground, mut wall) = ([0, 0], [0, 0]);
        for ((p, &rho), nrm) in img.xyz.iter().zip(&img.range).zip(&n) {
            if rho <= 0.0 {
                continue;
            }
            if (p[2] + 2.0).abs() < 1e-3 && rho < 35.0 {
                ground[0] += (nrm[2] > 0.999) as usize;
                ground[1] += 1;
            } else if (p[0] - 5.0).abs() < 1e-3 {
                wall[0] += (nrm[0] < -0.999) as usize;
                wall[1] += 1;
            }
        }
        assert!(ground[1] > 1000 && wall[1] > 100, "{ground:?} {wall:?}");
        assert!(ground[0] * 100 >= ground[1] * 98, "{ground:?}");
        assert!(wall[0] * 100 >= wall[1] * 95, "{wall:?}");
    }

    /// The normals written plainly: the surface test's `cos` / `sin` and the kernel's `exp`
    /// evaluated per pixel pair, every neighbour through [`RangeImage::offset`]; the
    /// smoothing along rows, then along columns of that.
    fn normals_reference(img: &RangeImage, window_m: f32, tan_theta: f32) -> Vec<[f32; 3]> {
        let half = |rho: f32, step: f32| -> usize {
            ((window_m / (rho * step).max(1e-9) * 0.5) as usize).min(MAX_HALF)
        };
        // One pass of the smoothing of `src`: along rows (`along_rows`) or along columns.
        let pass = |src: &[[f32; 3]], along_rows: bool| -> Vec<[f32; 3]> {
            let mut dst = src.to_vec();
            for (i, out) in dst.iter_mut().enumerate() {
                let (r, c) = (i / img.cols, i % img.cols);
                let rho = img.range[i];
                let step = if along_rows {
                    img.col_step
                } else {
                    img.row_step
                };
                let h = half(rho, step);
                if !img.valid(i) || h == 0 || window_m <= 0.0 {
                    continue;
                }
                let s = (h as f32).max(0.5);
                let (mut acc, mut wsum) = ([0.0f32; 3], 0.0f32);
                for d in -(h as isize)..=h as isize {
                    let (dr, dc) = if along_rows { (0, d) } else { (d, 0) };
                    let Some(j) = img.offset(r, c, dr, dc) else {
                        continue;
                    };
                    let alpha = img.step(dr, dc);
                    if !img.valid(j) || !same_surface(rho, img.range[j], alpha, tan_theta) {
                        continue;
                    }
                    let f = d as f32 / s;
                    let w = (-0.5 * f * f).exp();
                    (0..3).for_each(|k| acc[k] += w * src[j][k]);
                    wsum += w;
                }
                *out = acc.map(|v| v / wsum);
            }
            dst
        };
        let smooth = pass(&pass(&img.xyz, true), false);
        let mut out = vec![[0.0f32; 3]; img.len()];
        for (i, o) in out.iter_mut().enumerate() {
            let (r, c) = (i / img.cols, i % img.cols);
            if !img.valid(i) {
                continue;
            }
            let diff = |dr: isize, dc: isize| -> Option<[f32; 3]> {
                let alpha = img.step(dr, dc);
                let along = |s: isize| {
                    img.offset(r, c, dr * s, dc * s).filter(|&j| {
                        img.valid(j) && same_surface(img.range[i], img.range[j], alpha, tan_theta)
                    })
                };
                let (a, b) = match (along(1), along(-1)) {
                    (Some(a), Some(b)) => (a, b),
                    (Some(a), None) => (a, i),
                    (None, Some(b)) => (i, b),
                    (None, None) => return None,
                };
                Some(sub(smooth[a], smooth[b]))
            };
            if let (Some(v1), Some(v2)) = (diff(0, 1), diff(1, 0)) {
                let n = cross(v1, v2);
                let len = dot(n, n).sqrt();
                if len > 1e-12 {
                    let s = if dot(n, img.xyz[i]) > 0.0 { -1.0 } else { 1.0 };
                    *o = n.map(|v| s * v / len);
                }
            }
        }
        out
    }

    /// The tabulated trigonometry and kernel weights and the runs inside rows give the
    /// normals bit for bit, near the sensor (the largest windows), at range steps, holes and
    /// across the seam.
    #[test]
    fn tabulated_normals_match_the_reference_bit_for_bit() {
        // 357 columns: the smoothing's last block in each row is partial.
        for (rows, cols) in [(16, 360), (13, 357)] {
            normals_match_the_reference(rows, cols);
        }
    }

    fn normals_match_the_reference(rows: usize, cols: usize) {
        let mut pts = plane_and_wall(rows, cols);
        let mut rng = crate::rng::Rng(9);
        for p in pts.iter_mut() {
            if rng.u() < 0.05 {
                *p = [f32::NAN; 3];
            } else {
                // Noise up to 2 cm, and every tenth point pulled in by a quarter (range steps).
                let f = if rng.u() < 0.1 { 0.75 } else { 1.0 };
                *p = p.map(|v| f * v + rng.range(-0.02, 0.02) as f32);
            }
        }
        let img =
            RangeImage::organised(rows, cols, &pts, None, super::super::image::Order::RowMajor)
                .unwrap();
        for (window_m, deg) in [(0.3f32, 3f32), (1.0, 10.0), (0.05, 3.0)] {
            let t = deg.to_radians().tan();
            let bits = |v: Vec<[f32; 3]>| -> Vec<[u32; 3]> {
                v.iter().map(|x| x.map(f32::to_bits)).collect()
            };
            // Links across gaps give the same normals: the differences take adjacent
            // neighbours only.
            for max_gap_px in [0, 1, 2] {
                let jump = Jump {
                    tan_theta: t,
                    max_gap_px,
                };
                let got = normals(&img, window_m, &Links::new(&img, jump));
                assert!(got.iter().filter(|n| **n != [0.0; 3]).count() > rows * cols / 3);
                assert_eq!(
                    bits(got),
                    bits(normals_reference(&img, window_m, t)),
                    "window {window_m} m, {deg}°, gap {max_gap_px}"
                );
            }
        }
    }

    /// Every link is the neighbour `across` finds in its direction when the surface test
    /// holds for the pair, and none otherwise: the links back (left, up) included, across the
    /// seam and across gaps.
    #[test]
    fn links_are_the_searched_and_tested_neighbours_in_all_four_directions() {
        // Columns three times closer than rows, as on a spinning sensor: a test taking one
        // direction's beam angle for the other fails.
        let (rows, cols) = (16, 1080);
        let mut pts = plane_and_wall(rows, cols);
        let mut rng = crate::rng::Rng(4);
        for p in pts.iter_mut() {
            if rng.u() < 0.15 {
                *p = [f32::NAN; 3];
            } else if rng.u() < 0.1 {
                *p = p.map(|v| 0.7 * v);
            }
        }
        let img =
            RangeImage::organised(rows, cols, &pts, None, super::super::image::Order::RowMajor)
                .unwrap();
        assert!(img.wraps);
        for max_gap_px in [0, 1, 2] {
            let jump = Jump {
                tan_theta: 3f32.to_radians().tan(),
                max_gap_px,
            };
            let links = Links::new(&img, jump);
            let (mut linked, mut gaps) = (0, 0);
            for i in 0..img.len() {
                let (r, c) = (i / cols, i % cols);
                let dirs = [(0, 1), (0, -1), (1, 0), (-1, 0)];
                for (l, (dr, dc)) in links.around(i).into_iter().zip(dirs) {
                    let want = img
                        .across(r, c, dr, dc, max_gap_px)
                        .filter(|_| img.valid(i))
                        .filter(|&(j, k)| {
                            let alpha = img.step(k * dr, k * dc);
                            same_surface(img.range[i], img.range[j], alpha, jump.tan_theta)
                        })
                        .map(|(j, k)| (j as u32, k as u8));
                    assert_eq!(l, want, "pixel {i}, direction {dr} {dc}, gap {max_gap_px}");
                    linked += usize::from(l.is_some());
                    gaps += usize::from(l.is_some_and(|(_, k)| k > 1));
                }
            }
            assert!(linked > img.len(), "gap {max_gap_px}: {linked} links");
            // The pairs: every right and down link, pixels in order; those to the right
            // within a row apart, each pixel second in at most one of them.
            let pairs: Vec<[u32; 2]> = (0..img.len())
                .flat_map(|i| {
                    let [right, _, down, _] = links.around(i);
                    [right, down]
                        .into_iter()
                        .flatten()
                        .map(move |(j, _)| [i as u32, j])
                })
                .collect();
            let (row, other): (Vec<[u32; 2]>, Vec<[u32; 2]>) = pairs
                .iter()
                .partition(|&&[i, j]| j > i && i as usize / cols == j as usize / cols);
            assert_eq!(links.row_pairs(), row, "gap {max_gap_px}");
            assert_eq!(links.other_pairs(), other, "gap {max_gap_px}");
            let mut second = vec![0; img.len()];
            for &[_, j] in &row {
                second[j as usize] += 1;
            }
            assert!(second.iter().all(|&n| n <= 1), "gap {max_gap_px}");
            assert!(
                other.iter().any(|&[i, j]| j < i),
                "gap {max_gap_px}: no link across the seam"
            );
            assert_eq!(2 * pairs.len(), linked, "gap {max_gap_px}");
            assert_eq!(
                gaps > 0,
                max_gap_px > 0,
                "gap {max_gap_px}: {gaps} across gaps"
            );
        }
    }

    #[test]
    fn surfaces_are_separated_by_range_jumps() {
        let t = 10f32.to_radians().tan();
        let a = 0.5f32.to_radians();
        // A wall facing the sensor: equal ranges.
        assert!(same_surface(10.0, 10.0, a, t));
        // A pole 1 m in front of a wall 10 m away: β ≈ 5°.
        assert!(!same_surface(10.0, 9.0, a, t));
        // Ground at a 20° grazing angle: β ≈ 20° whatever the range.
        for d in [5.0f32, 40.0] {
            let next = d * 20f32.to_radians().sin() / (20f32 + 0.5).to_radians().sin();
            assert!(same_surface(d, next, a, t), "{d} {next}");
        }
    }
}
