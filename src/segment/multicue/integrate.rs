//! Integration of the cues' segmentations (paper §2.5).
//!
//! Repeatedly the largest remaining segment among all cues, by 3-D coverage `R ≈ Σ ρ`
//! (eq. 6), is taken; if its within-segment dispersion (RMS distance of its pixels' cue
//! values from their mean, in the cue's units) is acceptable — in its own cue and in every
//! cue marked [`CueSegments::veto`] — it becomes a segment of the result, and its pixels are
//! removed from every cue. A segment of another cue that lost pixels is regrouped into its
//! connected remainders, each with its coverage and dispersion recomputed. This runs until
//! the largest remaining segment covers less than `min_coverage`.
//!
//! Regrouping is lazy and exact: a segment's coverage only shrinks when pixels are taken, so
//! the heap's key is an upper bound; a segment popped with pixels gone is regrouped and its
//! pieces pushed back, and a segment popped intact is truly the largest.

use std::collections::BinaryHeap;

use super::cues::Links;
use super::image::RangeImage;

/// One cue's segmentation as the integration takes it.
pub struct CueSegments<'a> {
    /// Values per pixel (dimension `dim`, flattened), for the dispersion.
    pub values: &'a [f32],
    /// Dimension of a value.
    pub dim: usize,
    /// Segment label per pixel (0 = none).
    pub labels: Vec<u32>,
    /// Largest acceptable dispersion, cue units.
    pub max_dispersion: f32,
    /// This cue's dispersion limit also applies to the segments of the other cues (the
    /// paper checks a segment in its own cue only; see `MulticueParams::colour_veto`).
    pub veto: bool,
}

/// How the integration ends and what it keeps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rules {
    /// Stop when the largest remaining segment covers less than this (Σ range, metres).
    pub min_coverage: f32,
    /// Segments with fewer pixels are not accepted.
    pub min_pixels: usize,
}

/// Integrated result.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Integrated {
    /// Segment per pixel, 1.. in order of acceptance (0 = none).
    pub labels: Vec<u32>,
    /// Segments accepted.
    pub segments: u32,
    /// Accepted segments per cue (in the caller's cue order).
    pub from_cue: Vec<u32>,
    /// Candidates rejected for their dispersion.
    pub rejected: u32,
    /// Segments regrouped after losing pixels.
    pub regrouped: u32,
}

#[derive(PartialEq)]
struct Cand {
    coverage: f32,
    cue: usize,
    seg: u32,
}
impl Eq for Cand {}
impl PartialOrd for Cand {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Cand {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        // Largest coverage first; ties by cue, then lower segment id (deterministic).
        self.coverage
            .total_cmp(&o.coverage)
            .then_with(|| o.cue.cmp(&self.cue))
            .then_with(|| o.seg.cmp(&self.seg))
    }
}

/// Integrates the cues' segmentations of `img`.
pub fn integrate(
    img: &RangeImage,
    cues: &[CueSegments],
    rules: Rules,
    links: &Links,
) -> Integrated {
    let n = img.len();
    let mut owner = vec![0u32; n];
    // Pixels of each segment of each cue.
    let mut members: Vec<Members> = cues.iter().map(|c| Members::of(&c.labels)).collect();
    let mut heap = BinaryHeap::new();
    for (k, m) in members.iter().enumerate() {
        for s in 1..m.span.len() {
            let px = m.get(s as u32);
            if !px.is_empty() {
                push(&mut heap, coverage(img, px), k, s as u32, rules);
            }
        }
    }
    let mut out = Integrated {
        labels: Vec::new(),
        segments: 0,
        from_cue: vec![0; cues.len()],
        rejected: 0,
        regrouped: 0,
    };
    let mut stamp = vec![0u32; n];
    let mut stamp_now = 0u32;
    let (mut left, mut stack) = (Vec::new(), Vec::new());
    while let Some(c) = heap.pop() {
        if c.coverage < rules.min_coverage {
            break;
        }
        let m = &mut members[c.cue];
        let px = m.take(c.seg);
        left.clear();
        left.extend(px.iter().copied().filter(|&p| owner[p as usize] == 0));
        if left.len() < px.len() {
            // Lost pixels: regroup the remainder into connected pieces, push them back.
            out.regrouped += 1;
            stamp_now += 1;
            for &p in &left {
                stamp[p as usize] = stamp_now;
            }
            for &start in &left {
                if stamp[start as usize] != stamp_now {
                    continue;
                }
                let id = m.span.len() as u32;
                let from = m.px.len();
                piece(start, (&mut stamp, stamp_now), links, &mut stack, &mut m.px);
                m.px[from..].sort_unstable();
                m.span.push((from as u32, (m.px.len() - from) as u32));
                let piece = m.get(id);
                push(&mut heap, coverage(img, piece), c.cue, id, rules);
            }
            m.live += left.len();
            m.compact_if_sparse();
            continue;
        }
        if left.len() < rules.min_pixels {
            continue;
        }
        let spread = |k: usize| dispersion(cues[k].values, cues[k].dim, &left);
        let too_mixed = (0..cues.len())
            .filter(|&k| k == c.cue || cues[k].veto)
            .any(|k| spread(k) > cues[k].max_dispersion);
        if too_mixed {
            out.rejected += 1;
            continue;
        }
        out.segments += 1;
        out.from_cue[c.cue] += 1;
        for &p in &left {
            owner[p as usize] = out.segments;
        }
    }
    out.labels = owner;
    out
}

/// Pushes a candidate, unless it covers less than `rules.min_coverage`: the integration stops
/// at the first such candidate it pops, so one never changes what it does (the same test as
/// the stop's).
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn push(heap: &mut BinaryHeap<Cand>, coverage: f32, cue: usize, seg: u32, rules: Rules) {
    if !(coverage < rules.min_coverage) {
        heap.push(Cand { coverage, cue, seg });
    }
}

/// The pixels of each segment of one cue, in ascending order, as ranges of one list (a
/// counting sort of the labels: one allocation per cue instead of one per segment); the
/// pieces of regrouped segments are appended.
struct Members {
    px: Vec<u32>,
    /// Per segment id: start and length in `px` (length 0 once taken).
    span: Vec<(u32, u32)>,
    /// Pixels in the segments not taken yet: the rest of `px` is garbage.
    live: usize,
}

impl Members {
    fn of(labels: &[u32]) -> Self {
        let max = labels.iter().copied().max().unwrap_or(0) as usize;
        let mut span = vec![(0u32, 0u32); max + 1];
        for &l in labels {
            span[l as usize].1 += 1;
        }
        span[0].1 = 0;
        let mut at = 0;
        for s in span.iter_mut() {
            s.0 = at;
            at += s.1;
        }
        let mut px = vec![0u32; at as usize];
        let mut fill: Vec<u32> = span.iter().map(|s| s.0).collect();
        for (i, &l) in labels.iter().enumerate() {
            if l > 0 {
                px[fill[l as usize] as usize] = i as u32;
                fill[l as usize] += 1;
            }
        }
        Members {
            live: px.len(),
            px,
            span,
        }
    }

    /// Drops the pixels of taken segments once they are more than half of the list: a
    /// segment regrouped again and again appends its remainder each time, and without this
    /// the list could grow with the square of its size.
    fn compact_if_sparse(&mut self) {
        if self.px.len() <= 2 * self.live + 4096 {
            return;
        }
        let mut px = Vec::with_capacity(2 * self.live);
        for s in self.span.iter_mut().filter(|s| s.1 > 0) {
            let at = px.len() as u32;
            px.extend_from_slice(&self.px[s.0 as usize..(s.0 + s.1) as usize]);
            s.0 = at;
        }
        self.px = px;
    }

    fn get(&self, seg: u32) -> &[u32] {
        let (at, len) = self.span[seg as usize];
        &self.px[at as usize..(at + len) as usize]
    }

    /// The segment's pixels, which it no longer has.
    fn take(&mut self, seg: u32) -> &[u32] {
        let (at, len) = std::mem::take(&mut self.span[seg as usize]);
        self.live -= len as usize;
        &self.px[at as usize..(at + len) as usize]
    }
}

/// Σ range over the pixels (eq. 6 up to the constant angular step).
fn coverage(img: &RangeImage, px: &[u32]) -> f32 {
    // In eight lanes: one f32 sum is a chain of additions, each waiting for the last (a
    // quarter of the integration's time, `perf`); eight chains run side by side. The sum
    // differs from the sequential one in its last bits only.
    let mut lanes = [0.0f32; 8];
    let chunks = px.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for (s, &p) in lanes.iter_mut().zip(c) {
            *s += img.range[p as usize];
        }
    }
    let tail: f32 = rest.iter().map(|&p| img.range[p as usize]).sum();
    lanes.iter().sum::<f32>() + tail
}

/// RMS distance of the pixels' values from their mean.
fn dispersion(values: &[f32], dim: usize, px: &[u32]) -> f32 {
    // The cues' dimensions as constants: the loops over a value's components unrolled and
    // their bounds known (a fifth of the integration's instructions). The same sums in the
    // same order whatever the dimension.
    match dim {
        1 => dispersion_in::<1>(values, dim, px),
        3 => dispersion_in::<3>(values, dim, px),
        _ => dispersion_in::<0>(values, dim, px),
    }
}

/// [`dispersion`] of values of dimension `D`, or `dim` when `D` is 0.
fn dispersion_in<const D: usize>(values: &[f32], dim: usize, px: &[u32]) -> f32 {
    let dim = if D > 0 { D } else { dim };
    let n = px.len() as f64;
    let at = |p: u32| &values[p as usize * dim..(p as usize + 1) * dim];
    let mut mean = vec![0.0f64; dim];
    for &p in px {
        for (m, &v) in mean.iter_mut().zip(at(p)) {
            *m += v as f64;
        }
    }
    mean.iter_mut().for_each(|m| *m /= n);
    let mut ss = 0.0f64;
    for &p in px {
        for (m, &v) in mean.iter().zip(at(p)) {
            let d = v as f64 - m;
            ss += d * d;
        }
    }
    (ss / n).sqrt() as f32
}

/// The connected piece (linked neighbours, [`Links`]) of the pixels stamped `now` that holds
/// `start`, appended to `out` (unstamped as they are taken; `stack` is scratch).
fn piece(
    start: u32,
    (stamp, now): (&mut [u32], u32),
    links: &Links,
    stack: &mut Vec<usize>,
    out: &mut Vec<u32>,
) {
    stamp[start as usize] = 0;
    out.push(start);
    stack.push(start as usize);
    while let Some(i) = stack.pop() {
        for (j, _) in links.around(i).into_iter().flatten() {
            let j = j as usize;
            if stamp[j] == now {
                stamp[j] = 0;
                out.push(j as u32);
                stack.push(j);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::segment::multicue::image::tests::{flat_image as image, STRICT};

    /// One cue's segmentation of 1-D values.
    fn cue<'a>(values: &'a [f32], labels: Vec<u32>, max: f32, veto: bool) -> CueSegments<'a> {
        CueSegments {
            values,
            dim: 1,
            labels,
            max_dispersion: max,
            veto,
        }
    }

    /// A segment regrouped again and again (each time one pixel lost) keeps its pixels, and
    /// the member list stays within twice the live pixels instead of growing with the square.
    #[test]
    fn member_lists_survive_repeated_regrouping_and_stay_compact() {
        let n = 20_000u32;
        // Segment 1: the even pixels; segment 2: the odd ones.
        let labels: Vec<u32> = (0..n).map(|i| 1 + i % 2).collect();
        let mut m = Members::of(&labels);
        assert_eq!(m.get(1).len(), 10_000);
        assert!(m.get(2).iter().all(|&p| p % 2 == 1));
        let mut seg = 1u32;
        let mut want: Vec<u32> = (0..n).step_by(2).collect();
        let mut peak = 0;
        for _ in 0..2_000 {
            let px = m.take(seg).to_vec();
            assert_eq!(px, want);
            // Lost its first pixel: the remainder comes back as one new segment.
            want.remove(0);
            let from = m.px.len();
            m.px.extend_from_slice(&px[1..]);
            seg = m.span.len() as u32;
            m.span.push((from as u32, (m.px.len() - from) as u32));
            m.live += px.len() - 1;
            m.compact_if_sparse();
            peak = peak.max(m.px.len());
        }
        assert_eq!(m.get(seg), &want[..]);
        assert_eq!(m.get(2).len(), 10_000, "the untouched segment moved intact");
        assert!(m.get(2).iter().all(|&p| p % 2 == 1));
        assert_eq!(m.live, want.len() + 10_000);
        // Without compaction: 20,000 + the 2,000 remainders (about 18 M entries).
        assert!(peak <= 2 * (10_000 + 10_000) + 4096 + 10_000, "peak {peak}");
    }

    #[test]
    fn largest_acceptable_segment_first_and_remainders_regrouped() {
        // 4 × 10 pixels. Cue A: one segment over everything but with a high dispersion
        // (rejected). Cue B: columns 0-5 one segment (accepted first), 6-9 another. Cue C:
        // columns 4-9 as one segment: after B's first segment takes 4-5, its remainder 6-9
        // is regrouped and competes with B's second segment.
        let (rows, cols) = (4, 10);
        let img = image(rows, cols);
        let n = rows * cols;
        let va: Vec<f32> = (0..n).map(|i| (i % cols) as f32).collect();
        let vb = vec![0.0f32; n];
        let vc = vec![0.0f32; n];
        let lb: Vec<u32> = (0..n).map(|i| if i % cols < 6 { 1 } else { 2 }).collect();
        let lc: Vec<u32> = (0..n).map(|i| if i % cols >= 4 { 1 } else { 0 }).collect();
        let cues = vec![
            cue(&va, vec![1; n], 1.0, false),
            cue(&vb, lb, 1.0, false),
            cue(&vc, lc, 1.0, false),
        ];
        let rules = Rules {
            min_coverage: 1.0,
            min_pixels: 2,
        };
        let jump = STRICT;
        let out = integrate(&img, &cues, rules, &Links::new(&img, jump));
        assert_eq!(out.segments, 2);
        assert_eq!(out.rejected, 1);
        assert!(out.regrouped >= 1);
        for i in 0..n {
            let want = if i % cols < 6 { 1 } else { 2 };
            assert_eq!(out.labels[i], want, "pixel {i}");
        }
        // B's second segment (cue 1) ties C's remainder (cue 2) in coverage: the lower cue
        // index wins.
        assert_eq!(out.from_cue, vec![0, 2, 0]);
    }

    #[test]
    fn small_segments_end_the_integration() {
        let img = image(2, 4);
        let v = vec![0.0f32; 8];
        let cues = vec![cue(&v, vec![1, 1, 1, 1, 2, 2, 3, 3], 1.0, false)];
        let rules = Rules {
            min_coverage: 25.0,
            min_pixels: 1,
        };
        let out = integrate(&img, &cues, rules, &Links::new(&img, STRICT));
        assert_eq!(out.segments, 1);
        assert_eq!(out.labels, vec![1, 1, 1, 1, 0, 0, 0, 0]);
        // A coverage of exactly the minimum still counts (ranges of 10 m: 20 for a pair), for
        // a segment as it is and for a piece regrouped after losing pixels: a second cue's
        // segment over pixels 3-6 loses 3 and 4 to the first cue's larger segment.
        let rules = Rules {
            min_coverage: 20.0,
            ..rules
        };
        let pair = vec![cue(&v, vec![1, 1, 1, 1, 1, 2, 2, 0], 1.0, false)];
        let remainder = vec![
            cue(&v, vec![1, 1, 1, 1, 1, 0, 0, 0], 1.0, false),
            cue(&v, vec![0, 0, 0, 1, 1, 1, 1, 0], 1.0, false),
        ];
        for (cues, regrouped) in [(pair, 0), (remainder, 1)] {
            let out = integrate(&img, &cues, rules, &Links::new(&img, STRICT));
            assert_eq!(out.labels, vec![1, 1, 1, 1, 1, 2, 2, 0]);
            assert_eq!(out.regrouped, regrouped);
        }
    }

    #[test]
    fn a_vetoing_cue_rejects_segments_mixed_in_it() {
        // 4 × 10 pixels of one plane (cue N: one segment) in two colours, columns 0-4 and
        // 5-9 (cue C: two segments). N's segment is the largest; its own dispersion is nil.
        let (rows, cols) = (4, 10);
        let img = image(rows, cols);
        let n = rows * cols;
        let vn = vec![0.0f32; n];
        let vc: Vec<f32> = (0..n)
            .map(|i| if i % cols < 5 { 20.0 } else { 60.0 })
            .collect();
        let lc: Vec<u32> = (0..n).map(|i| if i % cols < 5 { 1 } else { 2 }).collect();
        let run = |veto: bool| {
            let cues = vec![
                cue(&vn, vec![1; n], 1.0, false),
                cue(&vc, lc.clone(), 10.0, veto),
            ];
            let rules = Rules {
                min_coverage: 1.0,
                min_pixels: 2,
            };
            integrate(&img, &cues, rules, &Links::new(&img, STRICT))
        };
        // As the paper: the plane is accepted whole, the colours' segments lose their pixels.
        let paper = run(false);
        assert_eq!((paper.segments, paper.from_cue.clone()), (1, vec![1, 0]));
        // With colour vetoing: the plane spreads 20 colour units, rejected; both colours taken.
        let vetoed = run(true);
        assert_eq!((vetoed.segments, vetoed.rejected), (2, 1));
        assert_eq!(vetoed.from_cue, vec![0, 2]);
        for i in 0..n {
            assert_eq!(
                vetoed.labels[i],
                if i % cols < 5 { 1 } else { 2 },
                "pixel {i}"
            );
        }
    }

    /// The coverage in lanes is the plain sum up to rounding, whatever the number of pixels
    /// left over after the lanes (each pixel counted once).
    #[test]
    fn coverage_is_the_sum_of_the_ranges() {
        let mut img = image(40, 50);
        let mut rng = crate::rng::Rng(4);
        img.range
            .iter_mut()
            .for_each(|r| *r = 1.0 + 79.0 * rng.u() as f32);
        for len in (0..=40).chain([999, 2000]) {
            let px: Vec<u32> = (0..len).map(|_| (rng.u() * 2000.0) as u32).collect();
            let want: f64 = px.iter().map(|&p| img.range[p as usize] as f64).sum();
            let got = coverage(&img, &px) as f64;
            assert!(
                (got - want).abs() <= 1e-5 * want.max(1.0),
                "{len}: {got} vs {want}"
            );
        }
    }

    /// The dispersion with the dimension as a constant (1, 3) or not (2, 4) is the RMS
    /// distance from the mean summed the plain way, bit for bit.
    #[test]
    fn dispersion_is_the_rms_distance_from_the_mean_in_any_dimension() {
        let mut rng = crate::rng::Rng(6);
        for dim in 1..=4 {
            let values: Vec<f32> = (0..100 * dim).map(|_| rng.u() as f32 * 10.0).collect();
            let px: Vec<u32> = (0..100).filter(|_| rng.u() < 0.6).collect();
            let n = px.len() as f64;
            let mut mean = vec![0.0f64; dim];
            for &p in &px {
                for k in 0..dim {
                    mean[k] += values[p as usize * dim + k] as f64;
                }
            }
            let mean: Vec<f64> = mean.iter().map(|m| m / n).collect();
            let mut ss = 0.0f64;
            for &p in &px {
                for k in 0..dim {
                    let d = values[p as usize * dim + k] as f64 - mean[k];
                    ss += d * d;
                }
            }
            let want = (ss / n).sqrt() as f32;
            assert_eq!(
                dispersion(&values, dim, &px).to_bits(),
                want.to_bits(),
                "{dim}"
            );
        }
    }
}
