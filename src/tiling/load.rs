//! Worker side of tiling: load a complete tile from its spill files, or split an over-dense
//! tile into quadrants (quadtree, same buffer width) without loading it.

use super::spill::{Part, SpillSet};
use super::TileJob;
use crate::error::{Error, Result};
use crate::geom::cell_representative;
use crate::model::{RecordLayout, Rect, Tile, TileName};
use crate::rng::{FastMap, FastSet};
use std::path::Path;

/// Points read per block when streaming spill files.
const BLOCK_POINTS: usize = 16 * 1024;

/// Per-point buffers a worker carries from one tile to the next: allocating them afresh for
/// every tile costs a page fault per 4 KiB touched, as much as reading the spill files.
#[derive(Debug, Default)]
pub struct TileBuffers {
    records: Vec<u8>,
    ids: Vec<u64>,
    xyz: Vec<[f64; 3]>,
}

impl TileBuffers {
    /// Takes a finished tile's buffers (`records` may have been moved out of the tile earlier
    /// and is given separately).
    pub fn reclaim(tile: &mut Tile, records: Vec<u8>) -> Self {
        TileBuffers {
            records,
            ids: std::mem::take(&mut tile.ids),
            xyz: std::mem::take(&mut tile.xyz),
        }
    }
}

/// Reads a tile's points into memory (core points first) in `spare`'s buffers, deleting its
/// spill files and freeing its in-memory tails.
///
/// With `far` set (and a far zone within the buffer: [`FarThin::applies`]), the buffer beyond
/// the kept zone keeps one representative per far cell, as a split child's does ([`FarThin`]):
/// a grid tile's buffer is the stages' contexts at full density plus a thin ring for the ground
/// filter's seeds instead of the whole buffer. The second value returned counts the buffer
/// points dropped that way (0 for a job [`split_job`] has thinned already).
pub fn load_tile(
    mut job: TileJob,
    layout: &RecordLayout,
    spare: TileBuffers,
    far: Option<FarThin>,
) -> Result<(Tile, u64)> {
    let rl = layout.record_len;
    let far = far.filter(|f| !job.far_thinned && f.applies(job.buffer_m));
    // Exact bound of what is kept (the kept zone lies within the counted one, see
    // `FarThin::count_m`), so the buffers are allocated once.
    let n = match far {
        Some(f) => {
            job.n_core
                + job
                    .n_buf
                    .min(job.n_kept + f.far_cells(job.core, job.buffer_m))
        }
        None => job.n_core + job.n_buf,
    } as usize;
    let TileBuffers {
        mut records,
        mut ids,
        mut xyz,
    } = spare;
    records.clear();
    ids.clear();
    xyz.clear();
    records.reserve_exact(n * rl);
    ids.reserve_exact(n);
    xyz.reserve_exact(n);
    let mut push = |id: u64, rec: &[u8], p: [f64; 3]| {
        records.extend_from_slice(rec);
        ids.push(id);
        xyz.push(p);
    };
    job.core_part.for_each(rl, BLOCK_POINTS, |id, rec| {
        push(id, rec, layout.stage_xyz(rec));
        Ok(())
    })?;
    let mut thinned = 0;
    match far {
        None => job.buf_part.for_each(rl, BLOCK_POINTS, |id, rec| {
            push(id, rec, layout.stage_xyz(rec));
            Ok(())
        })?,
        Some(f) => {
            let near = f.near_cells(job.core);
            let cell_m = f.cells.cell_m;
            let key = |p: [f64; 3]| (cell_of(p[0], cell_m), cell_of(p[1], cell_m));
            let mut keeper = FarKeeper::new(f.cells, rl);
            // Per slab slot of the keeper: the point's place in the buffer (its ordinal, and
            // how many kept-whole points come before it).
            let mut place: Vec<(u64, u64)> = Vec::new();
            let mut note = |slot: Option<u32>, at: (u64, u64)| {
                if let Some(s) = slot.map(|s| s as usize) {
                    if place.len() <= s {
                        place.resize(s + 1, (0, 0));
                    }
                    place[s] = at;
                }
            };
            let (mut seq, mut whole) = (0u64, 0u64);
            job.buf_part.for_each(rl, BLOCK_POINTS, |id, rec| {
                let p = layout.stage_xyz(rec);
                let k = key(p);
                if in_cells(near, k) {
                    push(id, rec, p);
                    whole += 1;
                } else {
                    note(keeper.offer(k, p[2], id, rec), (seq, whole));
                }
                seq += 1;
                Ok(())
            })?;
            if !keeper.undecided().is_empty() {
                // Only cells `undecided` opened take points (near cells were never offered).
                let (mut seq, mut whole) = (0u64, 0u64);
                job.buf_part.for_each(rl, BLOCK_POINTS, |id, rec| {
                    let p = layout.stage_xyz(rec);
                    let k = key(p);
                    if in_cells(near, k) {
                        whole += 1;
                    } else {
                        note(keeper.offer_all(k, p[2], id, rec), (seq, whole));
                    }
                    seq += 1;
                    Ok(())
                })?;
            }
            let offered = keeper.offered;
            let mut reps: Vec<((u64, u64), u64, usize)> = Vec::new();
            let mut rep_records = Vec::new();
            let kept = keeper.drain(|id, rec, slot| {
                reps.push((place[slot as usize], id, reps.len()));
                rep_records.extend_from_slice(rec);
                Ok(())
            })?;
            thinned = offered - kept;
            // The representatives go where they were in the buffer: the tile is the unthinned
            // tile less the dropped points, in the same order, so the ground filter's ties
            // (broken by point index) fall as without thinning.
            reps.sort_unstable_by_key(|r| r.0 .0);
            let first = job.n_core as usize;
            let mut read = records.len() / rl;
            let total = read + reps.len();
            records.resize(total * rl, 0);
            ids.resize(total, 0);
            xyz.resize(total, [0.0; 3]);
            let mut write = total;
            for &((_, before), id, r) in reps.iter().rev() {
                while read > first + before as usize {
                    read -= 1;
                    write -= 1;
                    records.copy_within(read * rl..(read + 1) * rl, write * rl);
                    ids[write] = ids[read];
                    xyz[write] = xyz[read];
                }
                write -= 1;
                let rec = &rep_records[r * rl..(r + 1) * rl];
                records[write * rl..(write + 1) * rl].copy_from_slice(rec);
                ids[write] = id;
                xyz[write] = layout.stage_xyz(rec);
            }
        }
    }
    remove_spill(&mut job);
    let tile = Tile {
        id: job.id,
        name: job.name,
        core: job.core,
        buffer_m: job.buffer_m,
        records,
        ids,
        xyz,
        n_core: job.n_core as usize,
        segments: Vec::new(),
        segment_table: Vec::new(),
    };
    Ok((tile, thinned))
}

fn remove_spill(job: &mut TileJob) {
    job.core_part.release();
    job.buf_part.release();
}

/// How [`split_job`] splits.
#[derive(Debug, Clone, Copy)]
pub struct SplitParams {
    /// Smallest core edge, metres: a split below it is a budget error.
    pub min_tile_size_m: f64,
    /// Bound on the children's spill write buffers, bytes.
    pub buffer_bytes: usize,
    /// Points a tile may hold at this budget (for the error message).
    pub max_points: u64,
    /// Buffer points within this distance of a child's core are counted
    /// ([`TileJob::n_near`]).
    pub near_m: f64,
    /// Far-buffer thinning, if any ([`FarThin`]).
    pub far: Option<FarThin>,
}

/// Splits a tile into its four quadrants, streaming its spill files into the children's.
/// Children without core points are dropped (their buffer points are written by their own
/// core tiles). Fails when the quadrants would be narrower than `min_tile_size_m`.
///
/// With `far` set, a child's far buffer cells keep only their representative point (see
/// [`FarThin`]); the second value returned counts the buffer point copies dropped that way.
pub fn split_job(
    mut job: TileJob,
    layout: &RecordLayout,
    spill_dir: &Path,
    params: SplitParams,
) -> Result<(Vec<TileJob>, u64)> {
    let SplitParams {
        min_tile_size_m,
        buffer_bytes,
        near_m,
        far,
        ..
    } = params;
    let half = job.core.width() / 2.0;
    if half < min_tile_size_m {
        let e = too_dense(&job, &params);
        // The job ends here (a keep-going run goes on without it): its spill goes now.
        remove_spill(&mut job);
        return Err(e);
    }
    let quads: Vec<_> = (0u8..4)
        .map(|q| (job.id.child(q), job.core.quadrant(q)))
        .collect();
    let rl = layout.record_len;
    let mut set = SpillSet::new(spill_dir, buffer_bytes);
    let slots: Vec<usize> = quads.iter().map(|(cid, _)| set.slot(*cid)).collect();
    let b = job.buffer_m;
    let rects: Vec<Rect> = quads.iter().map(|(_, r)| *r).collect();
    let routing = Routing::new(&job, &rects, near_m, far);
    // Without thinning the keepers stay empty (`near` is None for every child).
    let rule = far.map_or(
        FarCells {
            cell_m: routing.cell_m,
            window_m: 0.0,
        },
        |f| f.cells,
    );
    let mut keepers: Vec<FarKeeper> = (0..4).map(|_| FarKeeper::new(rule, rl)).collect();
    routing.distribute(&job, layout, &mut set, &slots, &mut keepers)?;
    routing.collect_undecided(&job, layout, &mut keepers)?;
    remove_spill(&mut job);
    let mut thinned = 0;
    for (q, keeper) in keepers.into_iter().enumerate() {
        let offered = keeper.offered;
        let kept = keeper.drain(|pid, rec, _| set.push(slots[q], Part::Buffer, pid, rec))?;
        thinned += offered - kept;
    }
    let mut out = Vec::new();
    let mut total_core = 0;
    for (cid, rect) in quads {
        let done = set.finish(cid)?;
        let (n_core, n_buf) = (done.core.points(), done.buf.points());
        total_core += n_core;
        let mut child = TileJob {
            id: cid,
            name: TileName {
                id: cid,
                origin: job.name.origin,
            },
            core: rect,
            buffer_m: b,
            core_part: done.core,
            buf_part: done.buf,
            n_core,
            n_buf,
            n_near: done.near,
            n_kept: done.kept,
            far_thinned: far.is_some(),
        };
        if n_core == 0 {
            remove_spill(&mut child);
        } else {
            out.push(child);
        }
    }
    if total_core != job.n_core {
        return Err(Error::Internal(format!(
            "tile {}: split kept {total_core} of {} core points",
            job.name, job.n_core
        )));
    }
    Ok((out, thinned))
}

/// The budget error of a tile too dense to hold that cannot be split further.
fn too_dense(job: &TileJob, params: &SplitParams) -> Error {
    let SplitParams {
        min_tile_size_m,
        max_points,
        near_m,
        ..
    } = *params;
    Error::Budget(format!(
        "tile {}: {} points (core {} + buffer {}, {} of them within {} m of the core) in {:.3} m × {:.3} m exceed what a tile may hold at this memory budget (about {} points), and splitting further would go below tiling.min_tile_size_m = {} m; raise --memory-budget, use fewer --threads (each worker holds one tile), or narrow the stages' contexts (segment.context_m, label.context_m) or tiling.buffer_m",
        job.name,
        job.n_core + job.n_buf,
        job.n_core,
        job.n_buf,
        job.n_near,
        near_m,
        job.core.width(),
        job.core.width(),
        max_points,
        min_tile_size_m
    ))
}

/// Where the points of a tile being split go: its four children (by quadrant), their buffers
/// and far cells.
struct Routing {
    /// The parent core's midlines.
    xm: f64,
    ym: f64,
    /// Per child, its core expanded by the buffer width.
    outer: Vec<Rect>,
    /// Per child, its core expanded by `near_m` (buffer points counted in `n_near`).
    counted: Vec<Rect>,
    /// Per child, the range of far-grid cells touching its near zone: those are kept whole.
    /// None: the child keeps its whole buffer.
    near: Vec<Option<[i64; 4]>>,
    /// Far cell size, metres.
    cell_m: f64,
}

impl Routing {
    /// The routing of `job`'s points to the children with cores `rects`.
    fn new(job: &TileJob, rects: &[Rect], near_m: f64, far: Option<FarThin>) -> Self {
        let b = job.buffer_m;
        let xm = 0.5 * (job.core.x0 + job.core.x1);
        let ym = 0.5 * (job.core.y0 + job.core.y1);
        let outer: Vec<Rect> = rects.iter().map(|r| r.expanded(b)).collect();
        let counted: Vec<Rect> = rects.iter().map(|r| r.expanded(near_m)).collect();
        let cell_m = far.map_or(1.0, |f| f.cells.cell_m);
        let near: Vec<Option<[i64; 4]>> = rects
            .iter()
            .map(|r| far.filter(|f| f.applies(b)).map(|f| f.near_cells(*r)))
            .collect();
        Routing {
            xm,
            ym,
            outer,
            counted,
            near,
            cell_m,
        }
    }

    /// The child core a point belongs to: for a parent core point exactly one, decided by the
    /// midlines so that rounding can never drop or duplicate it; None for a buffer point.
    fn core_child(&self, parent_core: bool, x: f64, y: f64) -> Option<usize> {
        parent_core.then_some((x >= self.xm) as usize | (((y >= self.ym) as usize) << 1))
    }

    /// The far cell of a point for child q, None when the child keeps it in full.
    fn far_cell(&self, q: usize, x: f64, y: f64) -> Option<(i64, i64)> {
        self.far_key(q, (cell_of(x, self.cell_m), cell_of(y, self.cell_m)))
    }

    /// [`Routing::far_cell`] of a point in far-grid cell `(cx, cy)`.
    #[inline]
    fn far_key(&self, q: usize, key: (i64, i64)) -> Option<(i64, i64)> {
        (!in_cells(self.near[q]?, key)).then_some(key)
    }

    /// First pass over the parent's points: core and near buffer points into the children's
    /// spill files (`slots` in `set`), far buffer points offered to the children's `keepers`.
    fn distribute(
        &self,
        job: &TileJob,
        layout: &RecordLayout,
        set: &mut SpillSet,
        slots: &[usize],
        keepers: &mut [FarKeeper],
    ) -> Result<()> {
        let rl = layout.record_len;
        let parts = [(&job.core_part, true), (&job.buf_part, false)];
        for (part, parent_core) in parts {
            part.for_each(rl, BLOCK_POINTS, |pid, rec| {
                let [x, y, z] = layout.xyz(rec);
                let core_q = self.core_child(parent_core, x, y);
                // The far cell, the same for every child (two `floor`s, once per point).
                let cell = (cell_of(x, self.cell_m), cell_of(y, self.cell_m));
                for q in 0..4 {
                    if core_q == Some(q) {
                        set.push(slots[q], Part::Core, pid, rec)?;
                    } else if self.outer[q].contains(x, y) {
                        match self.far_key(q, cell) {
                            Some(key) => {
                                keepers[q].offer(key, z, pid, rec);
                            }
                            None => {
                                set.push(slots[q], Part::Buffer, pid, rec)?;
                                if self.counted[q].contains(x, y) {
                                    set.count_near(slots[q]);
                                }
                                // Kept whole (a split child's count is exact).
                                if self.near[q].is_some() {
                                    set.count_kept(slots[q]);
                                }
                            }
                        }
                    }
                }
                Ok(())
            })?;
        }
        Ok(())
    }

    /// Cells whose lowest points left their representative open (a run of sparse low points):
    /// a second pass collects all their points. Rare: 96 of ~270 k far cells over the 6.25 m
    /// leaves of the CycloMedia tile.
    fn collect_undecided(
        &self,
        job: &TileJob,
        layout: &RecordLayout,
        keepers: &mut [FarKeeper],
    ) -> Result<()> {
        let rl = layout.record_len;
        let parts = [(&job.core_part, true), (&job.buf_part, false)];
        let undecided: Vec<_> = keepers.iter_mut().map(|k| k.undecided()).collect();
        if undecided.iter().any(|u| !u.is_empty()) {
            for (part, parent_core) in parts {
                part.for_each(rl, BLOCK_POINTS, |pid, rec| {
                    let [x, y, z] = layout.xyz(rec);
                    let core_q = self.core_child(parent_core, x, y);
                    for q in 0..4 {
                        if core_q != Some(q)
                            && !undecided[q].is_empty()
                            && self.outer[q].contains(x, y)
                        {
                            if let Some(key) =
                                self.far_cell(q, x, y).filter(|k| undecided[q].contains(k))
                            {
                                keepers[q].offer_all(key, z, pid, rec);
                            }
                        }
                    }
                    Ok(())
                })?;
            }
        }
        Ok(())
    }
}

/// Lowest points held per far cell while splitting. The representative is nearly always among
/// the lowest few (the lowest point with 1–8 others within the ground window above it); for a
/// cell where these do not decide it a second pass collects all its points.
pub const FAR_KEEP: usize = 16;

/// The cells beyond the other stages' context in which a stage reading the whole buffer only
/// uses one representative point (see [`crate::geom::cell_representative`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FarCells {
    /// Cell size, metres (aligned to absolute multiples).
    pub cell_m: f64,
    /// Height window of the representative rule, metres.
    pub window_m: f64,
}

/// Thinning of the far part of a tile's buffer: as a grid tile loads ([`load_tile`]), and as
/// a split hands points to its children ([`split_job`]).
///
/// Why, for every tile: the ground filter needs the whole buffer width, the other stages only
/// their context of the core; 50 m tiles with a 20 m buffer on a street otherwise carried and
/// ground-filtered 3.3 tile points per input point (the demo), 2.0 thinned, with the same
/// output bit for bit (demo, simulated drive; on ISPRS FSite5 2 points of 1 of 218 tiles
/// changed: the filter's tile extent and border levels still read every point). Why, for
/// splits: a quadtree child keeps the parent's buffer width (the ground filter needs a whole
/// seed cell of context), so a deep split of a dense tile would otherwise copy and load the full
/// buffer for every small child: at four levels a 3 m core carried a 43 m square of buffer
/// (~200× its own points) and the split never converged on a simulated drive. Stages other
/// than the ground filter work within their context of the core and keep every point there;
/// beyond it the ground filter (with `densify_cell_m` > 0) seeds and densifies only from one
/// representative per `densify_cell_m` cell and labels the rest in a final pass whose result
/// for buffer points nobody reads. So each far cell keeps exactly that representative, chosen
/// by the filter's own rule from the cell's full point count, and the filter sees the same
/// candidates as without thinning. Near or far is decided per whole cell (a cell touching the
/// near zone is kept whole), so no cell is cut in two. (An earlier version kept the lowest 8
/// points per cell: the filter then picked other representatives, and keeping full density
/// only to 5 m changed 0.8 % of a split CycloMedia tile's segmentation; it needed 15 m.)
/// Buffer points are never written, only core points are, so no output point is lost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FarThin {
    /// Buffer points within this distance of the tile's core are all kept, metres (at least
    /// the stages' contexts and `tiling.dense_buffer_m`).
    pub near_m: f64,
    /// Cells and rule of the far zone.
    pub cells: FarCells,
}

impl FarThin {
    /// Whether a tile with this buffer width has a far zone at all.
    pub fn applies(&self, buffer_m: f64) -> bool {
        self.near_m < buffer_m
    }

    /// The far-grid cells kept whole around `core`: those touching its near zone
    /// (`[x0, y0, x1, y1]`, inclusive).
    pub fn near_cells(&self, core: Rect) -> [i64; 4] {
        let n = core.expanded(self.near_m);
        let c = self.cells.cell_m;
        [
            cell_of(n.x0, c),
            cell_of(n.y0, c),
            cell_of(n.x1, c),
            cell_of(n.y1, c),
        ]
    }

    /// Distance from the core within which every point of the cells kept whole lies (a cell
    /// touching the near zone reaches at most one cell beyond it; a millimetre more for the
    /// rounding of `floor`): the tiler and the split count buffer points within it as near
    /// ([`TileJob::n_near`]), so near + far cells bound a thinned tile's points.
    pub fn count_m(&self) -> f64 {
        self.near_m + self.cells.cell_m + 1e-3
    }

    /// Most far cells (hence kept far points) of a tile with this core and buffer: the cells
    /// of the buffered square minus those kept whole.
    pub fn far_cells(&self, core: Rect, buffer_m: f64) -> u64 {
        let c = self.cells.cell_m;
        let o = core.expanded(buffer_m);
        let span = |a: i64, b: i64| (b - a + 1).max(0) as u64;
        let outer =
            span(cell_of(o.x0, c), cell_of(o.x1, c)) * span(cell_of(o.y0, c), cell_of(o.y1, c));
        let [x0, y0, x1, y1] = self.near_cells(core);
        outer.saturating_sub(span(x0, x1) * span(y0, y1))
    }
}

/// Whether far-grid cell `key` lies in the inclusive cell range `[x0, y0, x1, y1]`.
#[inline]
fn in_cells([x0, y0, x1, y1]: [i64; 4], (cx, cy): (i64, i64)) -> bool {
    (x0..=x1).contains(&cx) && (y0..=y1).contains(&cy)
}

/// A kept far point: height, point id, slab slot.
type Kept = (f64, u64, u32);

/// Per far cell of one child: its point count and lowest [`FAR_KEEP`] points (records in a
/// slab), then its representative.
struct FarKeeper {
    rule: FarCells,
    rl: usize,
    /// Per cell: point count and kept (z, point id, slab slot), sorted by (z, point id).
    cells: FastMap<(i64, i64), (u64, Vec<Kept>)>,
    /// Cells whose lowest points do not decide the representative: all their points.
    all: FastMap<(i64, i64), Vec<Kept>>,
    slab: Vec<u8>,
    offered: u64,
}

impl FarKeeper {
    fn new(rule: FarCells, rl: usize) -> Self {
        FarKeeper {
            rule,
            rl,
            cells: FastMap::default(),
            all: FastMap::default(),
            slab: Vec::new(),
            offered: 0,
        }
    }

    /// First pass: one far point. Returns the slab slot it was stored in, if it was held.
    fn offer(&mut self, key: (i64, i64), z: f64, pid: u64, rec: &[u8]) -> Option<u32> {
        self.offered += 1;
        let (count, cell) = self.cells.entry(key).or_default();
        *count += 1;
        // Most points of a dense cell lie above its full list of lowest: no search for them.
        if cell.len() == FAR_KEEP && cell.last().is_some_and(|e| (e.0, e.1) < (z, pid)) {
            return None;
        }
        // Sorted by (z, point id): the result does not depend on the order points arrive in.
        let pos = cell.partition_point(|e| (e.0, e.1) < (z, pid));
        if cell.len() < FAR_KEEP {
            let slot = (self.slab.len() / self.rl) as u32;
            self.slab.extend_from_slice(rec);
            cell.insert(pos, (z, pid, slot));
            Some(slot)
        } else if pos < FAR_KEEP {
            // Evict the highest and reuse its slab slot.
            let (_, _, slot) = cell.pop().unwrap_or((0.0, 0, 0));
            let at = slot as usize * self.rl;
            self.slab[at..at + self.rl].copy_from_slice(rec);
            cell.insert(pos, (z, pid, slot));
            Some(slot)
        } else {
            None
        }
    }

    /// Cells whose held points do not decide the representative; prepares to receive all
    /// their points ([`FarKeeper::offer_all`], second pass).
    fn undecided(&mut self) -> FastSet<(i64, i64)> {
        let w = self.rule.window_m;
        let open: FastSet<(i64, i64)> = self
            .cells
            .iter()
            .filter(|(_, (count, held))| {
                let count = usize::try_from(*count).unwrap_or(usize::MAX);
                cell_representative(count, held.len(), |j| held[j].0, w).is_none()
            })
            .map(|(k, _)| *k)
            .collect();
        for k in &open {
            self.all.insert(*k, Vec::new());
        }
        open
    }

    /// Second pass: one point of an undecided cell (others are ignored). Returns the slab slot
    /// it was stored in.
    fn offer_all(&mut self, key: (i64, i64), z: f64, pid: u64, rec: &[u8]) -> Option<u32> {
        let all = self.all.get_mut(&key)?;
        let slot = (self.slab.len() / self.rl) as u32;
        self.slab.extend_from_slice(rec);
        all.push((z, pid, slot));
        Some(slot)
    }

    /// Hands each cell's representative over (point id, record, slab slot), ordered by cell
    /// (deterministic); returns how many points that is.
    fn drain(mut self, mut f: impl FnMut(u64, &[u8], u32) -> Result<()>) -> Result<u64> {
        let w = self.rule.window_m;
        let mut cells: Vec<_> = self.cells.drain().collect();
        cells.sort_unstable_by_key(|c| c.0);
        let mut kept = 0;
        for (key, (count, held)) in cells {
            let chosen = match self.all.get_mut(&key) {
                Some(all) => {
                    all.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    cell_representative(all.len(), all.len(), |j| all[j].0, w).map(|j| all[j])
                }
                // Decided by its held points (`undecided` put every other cell in `all`).
                None => {
                    let count = usize::try_from(count).unwrap_or(usize::MAX);
                    cell_representative(count, held.len(), |j| held[j].0, w).map(|j| held[j])
                }
            };
            if let Some((_, pid, slot)) = chosen {
                kept += 1;
                let at = slot as usize * self.rl;
                f(pid, &self.slab[at..at + self.rl], slot)?;
            }
        }
        Ok(kept)
    }
}

/// Cell index of a coordinate on the absolute `cell_m` grid (the ground filter's cells).
fn cell_of(v: f64, cell_m: f64) -> i64 {
    (v / cell_m).floor() as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of a few cells offered in scrambled order: each cell hands over exactly the point
    /// the ground filter's rule picks from the whole cell (with its record), also the cells
    /// whose lowest FAR_KEEP points leave it open (second pass).
    #[test]
    fn far_keeper_hands_over_each_cells_representative() {
        let mut rng = crate::rng::Rng(0x2545_f491_4f6c_dd1d);
        let mut next = move || rng.next();
        let rule = FarCells {
            cell_m: 0.5,
            window_m: 0.15,
        };
        let mut keeper = FarKeeper::new(rule, 16);
        let mut expected = Vec::new();
        let mut offers = Vec::new();
        let mut open = 0;
        let mut pid = 0u64;
        for cell in 0..200i64 {
            let count = 1 + (next() % 200) as usize;
            let outliers = (next() % 24) as usize;
            let spread = [0.05, 0.5, 4.0][(next() % 3) as usize];
            let mut pts: Vec<(f64, u64)> = (0..count)
                .map(|i| {
                    pid += 1;
                    let u = (next() % 1000) as f64 / 1000.0;
                    let z = if i < outliers.min(count - 1) {
                        -0.3 - 0.4 * i as f64
                    } else {
                        u * spread
                    };
                    (z, pid)
                })
                .collect();
            for &(z, p) in &pts {
                offers.push(((cell, -cell), z, p));
            }
            pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let held = count.min(FAR_KEEP);
            if cell_representative(count, held, |j| pts[j].0, 0.15).is_none() {
                open += 1;
            }
            let whole = cell_representative(count, count, |j| pts[j].0, 0.15).unwrap();
            expected.push(pts[whole].1);
        }
        // Scramble the arrival order.
        for i in (1..offers.len()).rev() {
            offers.swap(i, (next() % (i as u64 + 1)) as usize);
        }
        let rec = |z: f64, p: u64| {
            let mut rec = [0u8; 16];
            rec[..8].copy_from_slice(&p.to_le_bytes());
            rec[8..].copy_from_slice(&z.to_le_bytes());
            rec
        };
        for &(key, z, p) in &offers {
            let _ = keeper.offer(key, z, p, &rec(z, p));
        }
        let undecided = keeper.undecided();
        assert_eq!(undecided.len(), open);
        assert!(open > 0 && open < 200, "{open}");
        for &(key, z, p) in &offers {
            if undecided.contains(&key) {
                keeper.offer_all(key, z, p, &rec(z, p)).unwrap();
            }
        }
        let mut got = Vec::new();
        let kept = keeper
            .drain(|p, rec, _| {
                assert_eq!(u64::from_le_bytes(rec[..8].try_into().unwrap()), p);
                got.push(p);
                Ok(())
            })
            .unwrap();
        assert_eq!(kept as usize, got.len());
        got.sort_unstable();
        expected.sort_unstable();
        assert_eq!(got, expected);
    }

    /// A test point: x, y, z, point id, part.
    type TestPoint = (f64, f64, f64, u64, Part);

    /// A grid tile's job (core 0..40 m, buffer 20 m, spill in `dir`) of a random cloud of
    /// `n` points, z in 0..3 m; also each point's (x, y, z, id, part).
    fn random_job(dir: &Path, layout: &RecordLayout, n: u64) -> (TileJob, Vec<TestPoint>) {
        use crate::model::TileId;
        let id = TileId::grid(0, 0);
        let core = Rect {
            x0: 0.0,
            y0: 0.0,
            x1: 40.0,
            y1: 40.0,
        };
        let mut rng = crate::rng::Rng(0x9e37_79b9_7f4a_7c15);
        let mut next = move || rng.u();
        let mut set = SpillSet::new(dir, 1 << 20);
        let slot = set.slot(id);
        let mut points = Vec::new();
        for pid in 0..n {
            let (x, y, z) = (-20.0 + 80.0 * next(), -20.0 + 80.0 * next(), 3.0 * next());
            let mut rec = vec![0u8; layout.record_len];
            for (k, v) in [x, y, z].into_iter().enumerate() {
                let raw = (v / 0.01).round() as i32;
                rec[4 * k..4 * k + 4].copy_from_slice(&raw.to_le_bytes());
            }
            let [x, y, z] = layout.xyz(&rec);
            let part = if core.contains(x, y) {
                Part::Core
            } else {
                Part::Buffer
            };
            set.push(slot, part, pid, &rec).unwrap();
            points.push((x, y, z, pid, part));
        }
        let done = set.finish(id).unwrap();
        let job = TileJob {
            id,
            name: TileName {
                id,
                origin: (0.0, 0.0),
            },
            core,
            buffer_m: 20.0,
            n_core: done.core.points(),
            n_buf: done.buf.points(),
            core_part: done.core,
            buf_part: done.buf,
            n_near: done.near,
            n_kept: done.kept,
            far_thinned: false,
        };
        (job, points)
    }

    fn test_layout() -> RecordLayout {
        use las::{point::Format, Transform, Vector};
        let t = Transform {
            scale: 0.01,
            offset: 0.0,
        };
        RecordLayout::new(Format::new(0).unwrap(), Vector { x: t, y: t, z: t })
    }

    fn test_far() -> FarThin {
        FarThin {
            near_m: 5.0,
            cells: FarCells {
                cell_m: 0.5,
                window_m: 0.15,
            },
        }
    }

    /// A grid tile loaded with far thinning: every core point and every buffer point of the
    /// cells kept whole, and of each far cell exactly the point the ground filter's rule picks
    /// from all of the cell's buffer points, in the unthinned tile's order; no more points than
    /// the budget's bound (core + points within `count_m` + far cells); without thinning (or
    /// thinned by a split already), every point.
    #[test]
    fn load_thins_a_grid_tiles_far_cells_to_their_representatives() {
        let dir = tempfile::tempdir().unwrap();
        let layout = test_layout();
        let far = test_far();
        let (job, points) = random_job(dir.path(), &layout, 60_000);
        let (core, b) = (job.core, job.buffer_m);
        let counted = core.expanded(far.count_m());
        let n_kept = points
            .iter()
            .filter(|p| p.4 == Part::Buffer && counted.contains(p.0, p.1))
            .count() as u64;
        let bound = job.n_core + n_kept + far.far_cells(core, b);
        // The loader sizes its buffers by the count (the tiler's; this job has none).
        let mut job = job;
        job.n_kept = n_kept;
        let near = far.near_cells(core);
        let key = |x: f64, y: f64| (cell_of(x, 0.5), cell_of(y, 0.5));
        // Expected: core, kept-zone buffer points, and per far cell its representative.
        let mut expected: Vec<u64> = Vec::new();
        let mut cells: FastMap<(i64, i64), Vec<(f64, u64)>> = FastMap::default();
        for &(x, y, z, pid, part) in &points {
            if part == Part::Core || in_cells(near, key(x, y)) {
                expected.push(pid);
                assert!(part == Part::Core || counted.contains(x, y));
            } else {
                cells.entry(key(x, y)).or_default().push((z, pid));
            }
        }
        for pts in cells.values_mut() {
            pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let j = cell_representative(pts.len(), pts.len(), |j| pts[j].0, 0.15).unwrap();
            expected.push(pts[j].1);
        }
        expected.sort_unstable();
        let n_core = job.n_core as usize;
        let (tile, thinned) = load_tile(job, &layout, TileBuffers::default(), Some(far)).unwrap();
        assert_eq!(tile.n_core, n_core);
        assert!(tile.ids[..n_core]
            .iter()
            .all(|&id| points[id as usize].4 == Part::Core));
        let mut got = tile.ids.clone();
        got.sort_unstable();
        assert_eq!(got, expected);
        assert_eq!(thinned as usize, points.len() - got.len());
        assert!(thinned > 20_000, "{thinned}");
        assert!(got.len() as u64 <= bound, "{} > {bound}", got.len());
        // In the order of the unthinned tile, records and positions with them.
        let (full_job, _) = random_job(dir.path(), &layout, 60_000);
        let (full, _) = load_tile(full_job, &layout, TileBuffers::default(), None).unwrap();
        let keep: FastSet<u64> = tile.ids.iter().copied().collect();
        let rl = layout.record_len;
        let same: Vec<usize> = (0..full.ids.len())
            .filter(|&i| keep.contains(&full.ids[i]))
            .collect();
        assert_eq!(same.len(), tile.ids.len());
        for (t, &i) in same.iter().enumerate() {
            assert_eq!(tile.ids[t], full.ids[i]);
            assert_eq!(tile.xyz[t], full.xyz[i]);
            assert_eq!(
                tile.records[t * rl..(t + 1) * rl],
                full.records[i * rl..(i + 1) * rl]
            );
        }
        // Without thinning (or a job a split has thinned) every point loads.
        let (mut job, _) = random_job(dir.path(), &layout, 60_000);
        job.far_thinned = true;
        let (tile, thinned) = load_tile(job, &layout, TileBuffers::default(), Some(far)).unwrap();
        assert_eq!((tile.ids.len(), thinned), (60_000, 0));
    }

    /// A split of a tile with a random cloud: every child's near zone (core + 5 m) holds all
    /// its points and is counted exactly in `n_near`; beyond it at most one point per far
    /// cell remains; every parent core point lands in exactly one child core.
    #[test]
    fn split_counts_near_points_and_thins_only_far_cells() {
        let dir = tempfile::tempdir().unwrap();
        let layout = test_layout();
        let (job, points) = random_job(dir.path(), &layout, 60_000);
        let far = test_far();
        let params = SplitParams {
            min_tile_size_m: 1.0,
            buffer_bytes: 1 << 20,
            max_points: 1,
            near_m: 5.0,
            far: Some(far),
        };
        let n_core = job.n_core;
        let (children, thinned) = split_job(job, &layout, dir.path(), params).unwrap();
        assert_eq!(children.len(), 4);
        assert!(thinned > 0);
        let mut cores = 0;
        for child in children {
            let near = child.core.expanded(5.0);
            let outer = child.core.expanded(20.0);
            let expect_near = points
                .iter()
                .filter(|&&(x, y, ..)| near.contains(x, y) && !child.core.contains(x, y))
                .count() as u64;
            assert_eq!(child.n_near, expect_near, "{}", child.name);
            let [cx0, cy0, cx1, cy1] = far.near_cells(child.core);
            let expect_kept = points
                .iter()
                .filter(|&&(x, y, ..)| {
                    let (cx, cy) = (cell_of(x, 0.5), cell_of(y, 0.5));
                    outer.contains(x, y)
                        && !child.core.contains(x, y)
                        && (cx0..=cx1).contains(&cx)
                        && (cy0..=cy1).contains(&cy)
                })
                .count() as u64;
            assert_eq!(child.n_kept, expect_kept, "{}", child.name);
            let core = child.core;
            let bound = child.n_core + child.n_kept + far.far_cells(core, 20.0);
            let (tile, again) =
                load_tile(child, &layout, TileBuffers::default(), Some(far)).unwrap();
            assert_eq!(again, 0, "a split child is thinned once");
            assert!(
                tile.ids.len() as u64 <= bound,
                "{} > {bound}",
                tile.ids.len()
            );
            cores += tile.n_core;
            assert!(tile.xyz[..tile.n_core]
                .iter()
                .all(|p| core.contains(p[0], p[1])));
            let mut far_cells = std::collections::HashSet::new();
            let mut in_near = 0;
            for p in &tile.xyz[tile.n_core..] {
                assert!(outer.contains(p[0], p[1]));
                if near.contains(p[0], p[1]) {
                    in_near += 1;
                } else {
                    let key = (cell_of(p[0], 0.5), cell_of(p[1], 0.5));
                    // Cells touching the near zone are kept whole; the others keep one point.
                    let touches = key.0 >= cell_of(near.x0, 0.5)
                        && key.0 <= cell_of(near.x1, 0.5)
                        && key.1 >= cell_of(near.y0, 0.5)
                        && key.1 <= cell_of(near.y1, 0.5);
                    assert!(
                        touches || far_cells.insert(key),
                        "two points in far cell {key:?}"
                    );
                }
            }
            assert_eq!(in_near, expect_near);
        }
        assert_eq!(cores as u64, n_core);
    }
}
