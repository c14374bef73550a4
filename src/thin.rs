//! Density reduction by minimum point spacing (Sapkota 2008, §5.3): a point is kept only if no
//! point kept before it lies closer than `spacing` (3-D distance, i.e. a sphere, because the
//! orientation of the surfaces is not known). Points are visited in input order, so the result is
//! deterministic for a given order and independent of how the input is cut into chunks.
//!
//! # Memory
//! Kept points are remembered in a hash grid with cells a hair larger than `spacing`, so a new
//! point is compared only with the kept points of its own and the 26 neighbouring cells. Nothing
//! is ever evicted: memory grows with the number of **kept** points, about 80–100 bytes each
//! (coordinates, a link, and the grid's hash entry per occupied cell). Kept points are at least
//! `spacing` apart, so this is bounded by the volume scanned, roughly
//! `surface area / spacing²` for surface-like data. For country-scale inputs the pipeline applies
//! a `Thinner` per tile (and calls [`Thinner::reset`] between tiles), which bounds it by the tile
//! size; points on either side of a tile border may then be closer than `spacing`.

use std::collections::HashMap;
use std::path::Path;

/// Errors of thinning.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ThinError {
    /// The spacing must be a positive finite distance.
    #[error("minimum point spacing must be positive and finite, got {0}")]
    BadSpacing(f64),
}

/// Cell size relative to `spacing`. Slightly larger than 1 so that two points closer than
/// `spacing` never land two cells apart through rounding of `x / cell` (which has relative error
/// ~1e-16 of the cell index): the guarantee holds while `|coordinate| / spacing < ~1e9`.
const CELL_MARGIN: f64 = 1.0 + 1e-6;

/// Sentinel for "no next point" in a cell's chain.
const NONE: usize = usize::MAX;

/// Streaming minimum-spacing thinner; see the module docs.
///
/// ```
/// use tessera::thin::Thinner;
/// let mut t = Thinner::new(0.5).unwrap();
/// assert_eq!(t.push_chunk(&[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]]), vec![true, false]);
/// // The next chunk is checked against points kept from earlier chunks.
/// assert_eq!(t.push_chunk(&[[0.0, 0.4, 0.0], [0.0, 0.5, 0.0]]), vec![false, true]);
/// assert_eq!((t.seen(), t.kept()), (4, 2));
/// ```
#[derive(Debug, Clone)]
pub struct Thinner {
    spacing_m: f64,
    spacing_sq: f64,
    cell_m: f64,
    /// Head of each occupied cell's chain of kept points (index into `kept_xyz`).
    cells: HashMap<[i64; 3], usize>,
    kept_xyz: Vec<[f64; 3]>,
    /// Next kept point in the same cell, or `NONE`.
    next: Vec<usize>,
    seen: u64,
}

impl Thinner {
    /// A thinner keeping points at least `spacing_m` apart.
    pub fn new(spacing_m: f64) -> Result<Self, ThinError> {
        if !spacing_m.is_finite() || spacing_m <= 0.0 {
            return Err(ThinError::BadSpacing(spacing_m));
        }
        Ok(Thinner {
            spacing_m,
            spacing_sq: spacing_m * spacing_m,
            cell_m: spacing_m * CELL_MARGIN,
            cells: HashMap::new(),
            kept_xyz: Vec::new(),
            next: Vec::new(),
            seen: 0,
        })
    }

    /// The minimum spacing, metres.
    pub fn spacing_m(&self) -> f64 {
        self.spacing_m
    }

    /// Offers one point; returns whether it is kept. Points with a non-finite coordinate are
    /// never kept (their distance to anything is undefined).
    pub fn offer(&mut self, p: [f64; 3]) -> bool {
        self.seen += 1;
        if !p.iter().all(|v| v.is_finite()) {
            return false;
        }
        let c = self.cell_of(&p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [c[0] + dx, c[1] + dy, c[2] + dz];
                    let mut i = match self.cells.get(&key) {
                        Some(&head) => head,
                        None => continue,
                    };
                    while i != NONE {
                        let q = &self.kept_xyz[i];
                        let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                        if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < self.spacing_sq {
                            return false;
                        }
                        i = self.next[i];
                    }
                }
            }
        }
        let idx = self.kept_xyz.len();
        self.kept_xyz.push(p);
        let head = self.cells.entry(c).or_insert(NONE);
        self.next.push(*head);
        *head = idx;
        true
    }

    /// Offers a chunk of points in order; returns one keep flag per point.
    pub fn push_chunk(&mut self, xyz: &[[f64; 3]]) -> Vec<bool> {
        let mut keep = Vec::with_capacity(xyz.len());
        self.push_chunk_into(xyz, &mut keep);
        keep
    }

    /// Like [`Thinner::push_chunk`], writing into a reused buffer (cleared first).
    pub fn push_chunk_into(&mut self, xyz: &[[f64; 3]], keep: &mut Vec<bool>) {
        keep.clear();
        keep.extend(xyz.iter().map(|p| self.offer(*p)));
    }

    /// Points offered so far.
    pub fn seen(&self) -> u64 {
        self.seen
    }

    /// Points kept so far.
    pub fn kept(&self) -> u64 {
        self.kept_xyz.len() as u64
    }

    /// Occupied grid cells.
    pub fn occupied_cells(&self) -> usize {
        self.cells.len()
    }

    /// Approximate heap bytes held (capacity-based; the hash map's own overhead is estimated).
    pub fn approx_heap_bytes(&self) -> usize {
        let entry = std::mem::size_of::<([i64; 3], usize)>() + 1;
        self.kept_xyz.capacity() * std::mem::size_of::<[f64; 3]>()
            + self.next.capacity() * std::mem::size_of::<usize>()
            + self.cells.capacity() * entry
    }

    /// Forgets all kept points (e.g. between tiles), keeping the spacing and the allocations.
    pub fn reset(&mut self) {
        self.cells.clear();
        self.kept_xyz.clear();
        self.next.clear();
        self.seen = 0;
    }

    fn cell_of(&self, p: &[f64; 3]) -> [i64; 3] {
        // `as` saturates for out-of-range values, which only merges far-away cells (still
        // correct, since distances are checked exactly).
        [
            (p[0] / self.cell_m).floor() as i64,
            (p[1] / self.cell_m).floor() as i64,
            (p[2] / self.cell_m).floor() as i64,
        ]
    }
}

/// Thins a whole point set at once; returns the keep mask.
pub fn thin(xyz: &[[f64; 3]], spacing_m: f64) -> Result<Vec<bool>, ThinError> {
    Ok(Thinner::new(spacing_m)?.push_chunk(xyz))
}

/// What [`thin_file`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ThinStats {
    /// Points read.
    pub seen: u64,
    /// Points written.
    pub kept: u64,
}

/// Thins a LAS/LAZ file into `output` (LAZ when its name ends in `.laz`), streaming the points in
/// file order. Records are copied byte for byte (every attribute, extra bytes included), with
/// the input's point format, VLRs and EVLRs; the header is written as LAS 1.4, which holds
/// every point format and return numbers up to 15 (a LAS 1.2 header cannot count return 6).
/// The output is written to a temporary file and renamed, so a failure leaves no partial file.
pub fn thin_file(input: &Path, output: &Path, spacing_m: f64) -> crate::Result<ThinStats> {
    use crate::Error;
    Thinner::new(spacing_m).map_err(|e| Error::Config(e.to_string()))?;
    let file = crate::io::input::scan_file(input, 0)?;
    // The spacing is metres; a file in feet is thinned at the same distance in its unit.
    let unit_m = crate::io::crs::metres_per_unit(&file.header);
    let mut thinner = Thinner::new(spacing_m / unit_m).map_err(|e| Error::Config(e.to_string()))?;
    if let (Ok(a), Ok(b)) = (std::fs::canonicalize(input), std::fs::canonicalize(output)) {
        if a == b {
            return Err(Error::Config(format!(
                "thin: the output {} is the input; write to another file",
                output.display()
            )));
        }
    }
    let layout =
        crate::model::RecordLayout::new(*file.header.point_format(), *file.header.transforms());
    let laz = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
    let mut b = las::Builder::from(file.header.clone());
    b.version = las::Version::new(1, 4);
    b.point_format.is_compressed = laz;
    b.vlrs.retain(|v| !las::laz::is_laszip_vlr(v));
    b.evlrs.retain(|v| !las::laz::is_laszip_vlr(v));
    b.padding.clear();
    b.vlr_padding.clear();
    b.point_padding.clear();
    let mut header = b.into_header().map_err(|e| {
        Error::Config(format!(
            "{}: cannot build the output header: {e}",
            output.display()
        ))
    })?;
    header.clear();
    if header.point_format().is_extended {
        crate::io::output::set_wkt(&mut header, &file.header)?;
    }
    let tmp = crate::io::output::tmp_path(output);
    let res = (|| -> crate::Result<u64> {
        let mut w = crate::io::laswrite::LasFile::create(&tmp, header, Default::default())?;
        let rl = layout.record_len;
        let mut kept = 0u64;
        let mut slab = las::PointDataBuilder::new()
            .with_format(layout.format)
            .with_transforms(layout.transforms)
            .build();
        let mut out: Vec<u8> = Vec::new();
        crate::io::input::read_file_chunks(
            &file,
            &layout,
            1 << 18,
            || None,
            |_, data| {
                out.clear();
                for rec in data.raw_bytes().chunks_exact(rl) {
                    if thinner.offer(layout.xyz(rec)) {
                        out.extend_from_slice(rec);
                    }
                }
                if !out.is_empty() {
                    slab.resize_for(out.len() / rl).copy_from_slice(&out);
                    w.write_points(&slab)?;
                    kept += (out.len() / rl) as u64;
                }
                Ok(())
            },
        )?;
        w.finish()?;
        Ok(kept)
    })();
    match res {
        Ok(kept) => {
            crate::io::output::commit_tmp(&tmp, output)?;
            Ok(ThinStats {
                seen: thinner.seen(),
                kept,
            })
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small deterministic generator (xorshift64*), to avoid a dependency.
    struct Rng(u64);

    impl Rng {
        fn unit(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn random_points(n: usize, seed: u64, scale: [f64; 3], offset: [f64; 3]) -> Vec<[f64; 3]> {
        let mut rng = Rng(seed);
        (0..n)
            .map(|_| {
                [
                    offset[0] + rng.unit() * scale[0],
                    offset[1] + rng.unit() * scale[1],
                    offset[2] + rng.unit() * scale[2],
                ]
            })
            .collect()
    }

    fn dist_sq(a: &[f64; 3], b: &[f64; 3]) -> f64 {
        (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
    }

    /// Brute force: kept points pairwise ≥ spacing; every dropped point is within spacing of a
    /// point kept before it (so the thinning is maximal, not just sparse).
    fn check_brute_force(pts: &[[f64; 3]], keep: &[bool], spacing: f64) {
        let s2 = spacing * spacing;
        let kept: Vec<usize> = (0..pts.len()).filter(|&i| keep[i]).collect();
        for (a, &i) in kept.iter().enumerate() {
            for &j in &kept[a + 1..] {
                let d = dist_sq(&pts[i], &pts[j]);
                assert!(d >= s2, "kept {i} and {j} are {} apart", d.sqrt());
            }
        }
        for i in (0..pts.len()).filter(|&i| !keep[i]) {
            assert!(
                kept.iter()
                    .any(|&j| j < i && dist_sq(&pts[i], &pts[j]) < s2),
                "dropped point {i} has no earlier kept point within spacing"
            );
        }
    }

    #[test]
    fn kept_points_respect_spacing_brute_force() {
        for (seed, spacing) in [(1u64, 0.2), (2, 0.05), (3, 0.5)] {
            let pts = random_points(2500, seed, [3.0, 2.0, 1.0], [0.0; 3]);
            let mut t = Thinner::new(spacing).expect("spacing");
            let mut keep = Vec::new();
            // Irregular chunks.
            let mut start = 0;
            let mut size = 1;
            while start < pts.len() {
                let end = (start + size).min(pts.len());
                keep.extend(t.push_chunk(&pts[start..end]));
                start = end;
                size = size * 3 % 97 + 1;
            }
            check_brute_force(&pts, &keep, spacing);
            assert_eq!(t.seen(), pts.len() as u64);
            assert_eq!(t.kept(), keep.iter().filter(|&&k| k).count() as u64);
        }
    }

    #[test]
    fn georeferenced_coordinates_and_exact_spacing() {
        // Far from the origin, with points exactly one spacing apart along a line (kept: the
        // rule is "not closer than") and between them (dropped).
        let base = [4.5e5, 5.7e6, 12.0];
        let mut pts = random_points(1500, 9, [2.0, 2.0, 0.5], base);
        let line: Vec<[f64; 3]> = (0..20)
            .map(|k| [base[0] - 10.0 + k as f64 * 0.25, base[1] - 10.0, base[2]])
            .collect();
        let mid: Vec<[f64; 3]> = (0..19)
            .map(|k| {
                [
                    base[0] - 10.0 + k as f64 * 0.25 + 0.125,
                    base[1] - 10.0,
                    base[2],
                ]
            })
            .collect();
        pts.extend(&line);
        pts.extend(&mid);
        let keep = thin(&pts, 0.25).expect("spacing");
        check_brute_force(&pts, &keep, 0.25);
        let n0 = pts.len() - line.len() - mid.len();
        assert!(keep[n0..n0 + line.len()].iter().all(|&k| k));
        assert!(keep[n0 + line.len()..].iter().all(|&k| !k));
    }

    #[test]
    fn deterministic_and_chunking_invariant() {
        let pts = random_points(5000, 42, [5.0, 5.0, 0.2], [0.0; 3]);
        let whole = thin(&pts, 0.1).expect("spacing");
        for chunk in [1usize, 7, 1000] {
            let mut t = Thinner::new(0.1).expect("spacing");
            let mut keep = Vec::new();
            let mut buf = Vec::new();
            for c in pts.chunks(chunk) {
                t.push_chunk_into(c, &mut buf);
                keep.extend_from_slice(&buf);
            }
            assert_eq!(keep, whole, "chunk size {chunk}");
        }
        // Reset forgets the past: thinning again gives the same answer.
        let mut t = Thinner::new(0.1).expect("spacing");
        let _ = t.push_chunk(&pts);
        t.reset();
        assert_eq!(t.push_chunk(&pts), whole);
    }

    /// On a densely sampled plane, greedy thinning in random order is random sequential
    /// adsorption of discs of diameter `spacing`: it jams at a covered fraction of ≈ 0.547, i.e.
    /// ≈ 0.547 · A / (π s² / 4) points. Hard bounds: hexagonal packing (0.9069) from above, and
    /// from below the discs of radius `s` around kept points must cover the square.
    #[test]
    fn kept_count_matches_expected_density() {
        let (side, s) = (10.0, 0.5);
        let pts = random_points(60_000, 7, [side, side, 0.0], [0.0; 3]);
        let kept = thin(&pts, s)
            .expect("spacing")
            .iter()
            .filter(|&&k| k)
            .count() as f64;
        let disc = std::f64::consts::PI * s * s / 4.0;
        let rsa = 0.547 * side * side / disc;
        // Discs of kept points may reach s/2 beyond the square's edges.
        let upper = 0.9069 * (side + s) * (side + s) / disc;
        let lower = side * side / (std::f64::consts::PI * s * s);
        assert!(
            kept > lower && kept < upper,
            "{kept} outside [{lower}, {upper}]"
        );
        let rel = (kept - rsa) / rsa;
        eprintln!(
            "density: {kept} kept of {}, RSA ≈ {rsa:.0}, bounds [{lower:.0}, {upper:.0}]",
            pts.len()
        );
        assert!(rel.abs() < 0.12, "{kept} kept, RSA expects ≈ {rsa:.0}");
    }

    #[test]
    fn rejects_bad_spacing_and_non_finite_points() {
        for s in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(Thinner::new(s), Err(ThinError::BadSpacing(_))));
        }
        let keep = thin(
            &[[f64::NAN, 0.0, 0.0], [0.0; 3], [0.0, f64::INFINITY, 0.0]],
            1.0,
        )
        .expect("spacing");
        assert_eq!(keep, vec![false, true, false]);
    }

    #[test]
    fn memory_grows_with_kept_points_only() {
        // All points at one spot: one kept, memory stays tiny however many are offered.
        let mut t = Thinner::new(1.0).expect("spacing");
        let same = vec![[1.0, 2.0, 3.0]; 100_000];
        let _ = t.push_chunk(&same);
        assert_eq!((t.kept(), t.occupied_cells()), (1, 1));
        assert!(t.approx_heap_bytes() < 1024, "{}", t.approx_heap_bytes());
    }
}
