//! The streaming stitcher: receives cell releases, tile summaries and cell completions in any
//! order the pipeline produces them, matches neighbouring tiles, and hands back tiles whose
//! segments all have final global ids — holding only the frontier.
//!
//! **When can a tile close?** Its summary is needed until every tile that shares overlap
//! points with it has arrived. Such a tile lies in the same grid cell (quadtree siblings) or
//! in one of the 8 neighbouring cells, and it shares points *inside this tile's core+buffer
//! region*. The tiler releases a cell only after every input reaching that region has been
//! read, and it opens a cell as soon as one of its core *or buffer* points is binned; so when
//! a cell is released, every cell that can share overlap points with it is either still open
//! in the tiler (the release says which) or was released before (the stitcher still knows it,
//! see below). A cell's tiles close once the cell and all those *relevant* cells are complete
//! (every leaf tile arrived, or released without core points).
//!
//! Cell entries are reference-counted by the open cells that list them, so a cell is
//! forgotten only when no later release can name it as a relevant neighbour (a relevant later
//! cell keeps it alive until that cell is complete). Memory therefore follows the frontier
//! of open cells, not the run.

use super::components::{node, split, Components, Final};
use super::pairs::match_pair;
use super::spill::{Extent, SpillFile};
use super::summary::{BorderRecord, BorderSummary};
use super::{CellKey, CellRelease, StitchError, StitchParams, StitchStats};
use crate::geom::cell_rect;
use crate::model::{Rect, TileId};
use crate::tiling::spill::FastHasher;
use std::collections::{BTreeSet, HashMap, HashSet};
use std::hash::BuildHasherDefault;

/// A tile whose segments all have their global ids.
#[derive(Debug)]
pub struct Ready<P> {
    /// What the caller attached to the tile.
    pub payload: P,
    /// Global id per local label `l` at index `l - 1` (0 for segments without core points).
    pub ids: Vec<u64>,
}

#[derive(Debug, Default)]
struct CellState {
    released: bool,
    done: bool,
    closed: bool,
    refs: u32,
    relevant: Vec<CellKey>,
    tiles: Vec<u32>,
    /// Quadtree leaves of a split cell that arrived, (level, path), and every ancestor of
    /// one; with `rect`, the cell's core: what [`Stitcher::trim_cell`] needs.
    arrived: NodeSet,
    ancestors: NodeSet,
    rect: Option<Rect>,
    /// Border records its open tiles hold, and how many they held after the last trim.
    held: u64,
    held_after_trim: u64,
}

type NodeSet = HashSet<(u8, u64), BuildHasherDefault<FastHasher>>;

/// A split cell's tiles are trimmed when the records they hold have doubled since the last
/// trim (and exceed this): amortised O(1) work per record instead of a pass per arriving leaf.
const TRIM_MIN_RECORDS: u64 = 100_000;

impl CellState {
    /// Whether `q` (clipped to the cell) lies inside the cores of arrived leaves; `node` is
    /// a quadtree node (level, path) with rectangle `r`.
    fn covered(&self, node: (u8, u64), r: Rect, q: &Rect) -> bool {
        if !r.intersects(q) || self.arrived.contains(&node) {
            return true;
        }
        if !self.ancestors.contains(&node) {
            return false;
        }
        (0u8..4).all(|c| self.covered((node.0 + 1, (node.1 << 2) | c as u64), r.quadrant(c), q))
    }
}

#[derive(Debug)]
struct TileState<P> {
    /// The border summary while the tile is open and it is in memory …
    summary: Option<BorderSummary>,
    /// … or while it waits in the spill file (with its record count and in-memory bytes).
    spilled: Option<(Extent, u64, u64)>,
    /// The tile, its core and name (kept when the summary is spilled).
    id: TileId,
    rect: Rect,
    name: String,
    ids: Vec<u64>,
    /// Per label: whether the segment has core points (is written by this tile).
    core: Vec<bool>,
    nodes: Vec<u32>,
    pending: u32,
    closed: bool,
    waiting: bool,
    payload: Option<P>,
}

fn neighbours8(c: CellKey) -> impl Iterator<Item = CellKey> {
    (-1..=1i64)
        .flat_map(move |dy| (-1..=1i64).map(move |dx| (c.0 + dx, c.1 + dy)))
        .filter(move |&n| n != c)
}

/// The stitcher. `P` is whatever the caller needs to write a tile once it is ready.
#[derive(Debug)]
pub struct Stitcher<P> {
    params: StitchParams,
    strip_m: f64,
    cells: HashMap<CellKey, CellState>,
    tiles: HashMap<u32, TileState<P>>,
    next_slot: u32,
    comps: Components,
    ready: Vec<Ready<P>>,
    stats: StitchStats,
    open_tiles: u64,
    held_records: u64,
    held_bytes: u64,
    waiting: u64,
    /// Summaries beyond `mem_cap` bytes go to `spill`, oldest first (`in_mem`: slots whose
    /// summary is in memory, in arrival order).
    spill: Option<SpillFile>,
    mem_cap: u64,
    in_mem: BTreeSet<u32>,
}

impl<P> Stitcher<P> {
    /// A stitcher for tiles segmented `strip_m` beyond their cores.
    pub fn new(params: StitchParams, strip_m: f64) -> Self {
        let stats = StitchStats {
            strip_m,
            min_shared_points: params.min_shared_points,
            majority_fraction: params.majority_fraction,
            ..Default::default()
        };
        Stitcher {
            params,
            strip_m,
            cells: HashMap::new(),
            tiles: HashMap::new(),
            next_slot: 0,
            comps: Components::default(),
            ready: Vec::new(),
            stats,
            open_tiles: 0,
            held_records: 0,
            held_bytes: 0,
            waiting: 0,
            spill: None,
            mem_cap: u64::MAX,
            in_mem: BTreeSet::new(),
        }
    }

    /// Keeps at most `cap_bytes` of border summaries in memory; the oldest beyond that wait
    /// in a spill file in `dir` (see [`super::spill`]).
    pub fn spill_beyond(mut self, dir: &std::path::Path, cap_bytes: u64) -> Self {
        self.spill = Some(SpillFile::new(dir));
        self.mem_cap = cap_bytes;
        self
    }

    /// Statistics so far.
    pub fn stats(&self) -> &StitchStats {
        &self.stats
    }

    /// Cell entries held (frontier bookkeeping; for tests of boundedness).
    pub fn cells_held(&self) -> usize {
        self.cells.len()
    }

    /// Tiles whose summaries are held right now.
    pub fn open_tiles(&self) -> u64 {
        self.open_tiles
    }

    /// Tiles whose ids are all final, in the order they became ready.
    pub fn take_ready(&mut self) -> Vec<Ready<P>> {
        std::mem::take(&mut self.ready)
    }

    /// The tiler released a batch of cells. Cells released together may list each other as
    /// open neighbours, so cells with core points are registered first: an empty cell of the
    /// batch must find the entries that wait for it.
    pub fn released(&mut self, batch: &[CellRelease]) {
        for r in batch.iter().filter(|r| r.has_core) {
            self.release_one(r);
        }
        for r in batch.iter().filter(|r| !r.has_core) {
            self.release_one(r);
        }
    }

    fn release_one(&mut self, r: &CellRelease) {
        if !r.has_core {
            if let Some(e) = self.cells.get_mut(&r.cell) {
                e.released = true;
                e.done = true;
                e.closed = true;
                self.cell_completed(r.cell);
            }
            return;
        }
        let mut relevant: Vec<CellKey> = r
            .open_neighbours
            .iter()
            .copied()
            .filter(|&n| n != r.cell)
            .chain(neighbours8(r.cell).filter(|n| self.cells.contains_key(n)))
            .collect();
        relevant.sort_unstable();
        relevant.dedup();
        for d in &relevant {
            self.cells.entry(*d).or_default().refs += 1;
        }
        let e = self.cells.entry(r.cell).or_default();
        e.released = true;
        e.relevant = relevant;
    }

    /// A worker processed a tile of a released cell. `summary` is its border summary.
    pub fn add_tile(&mut self, summary: BorderSummary, payload: P) -> Result<(), StitchError> {
        summary.validate()?;
        let cell = (summary.tile.ix, summary.tile.iy);
        match self.cells.get(&cell) {
            Some(e) if e.released && !e.done => {}
            _ => {
                return Err(StitchError::UnknownCell {
                    tile: summary.name.clone(),
                    cell,
                })
            }
        }
        let slot = self.next_slot;
        self.next_slot += 1;
        let n = summary.labels();
        let mut has_records = vec![false; n];
        for r in summary.inner.iter().chain(&summary.outer) {
            has_records[r.label as usize - 1] = true;
        }
        // Segments without border records cannot meet another tile: final at once. The rest
        // become union–find nodes.
        let mut ids = vec![0u64; n];
        let mut nodes = Vec::new();
        for (i, (&a, &rec)) in summary.anchors.iter().zip(&has_records).enumerate() {
            if a != u64::MAX {
                self.stats.local_segments += 1;
            }
            if rec {
                self.comps.insert(node(slot, i as u32 + 1), a);
                nodes.push(i as u32 + 1);
            } else if a != u64::MAX {
                ids[i] = a + 1;
                self.stats.global_segments += 1;
                self.stats.max_tiles_per_segment = self.stats.max_tiles_per_segment.max(1);
            }
        }
        // Match against every arrived, still open tile nearby (same cell or the 8 around).
        let reach = summary.core.expanded(self.strip_m);
        let mut others: Vec<u32> = std::iter::once(cell)
            .chain(neighbours8(cell))
            .filter_map(|c| self.cells.get(&c))
            .flat_map(|c| c.tiles.iter().copied())
            .collect();
        others.sort_unstable();
        for o in others {
            let Some(t) = self.tiles.get(&o) else {
                continue;
            };
            if !reach.intersects(&t.rect) {
                continue;
            }
            let loaded;
            let other = match (&t.summary, t.spilled, &mut self.spill) {
                (Some(s), _, _) => s,
                (None, Some((x, _, _)), Some(sp)) => {
                    loaded = sp.read(x, &t.name)?;
                    &loaded
                }
                _ => continue,
            };
            let m = match_pair(&summary, other, self.strip_m, &self.params);
            if m.shared_points == 0 && m.candidates == 0 {
                continue;
            }
            self.stats.tile_pairs += 1;
            self.stats.shared_points += m.shared_points;
            self.stats.candidate_pairs += m.candidates;
            self.stats.rejected_pairs += m.rejected;
            self.stats.accepted_pairs += m.merge.len() as u64;
            for (la, lb) in m.merge {
                if self.comps.union(node(slot, la), node(o, lb)) {
                    self.stats.merges += 1;
                }
            }
        }
        // Room for the new summary first (it was matched above against what is in memory), so
        // the frontier in memory stays within the cap unless one summary alone exceeds it.
        self.spill_over_cap(summary.bytes() as u64)?;
        self.stats.tiles += 1;
        self.open_tiles += 1;
        self.held_records += summary.records() as u64;
        self.held_bytes += summary.bytes() as u64;
        let s = &mut self.stats;
        s.frontier_tiles_max = s.frontier_tiles_max.max(self.open_tiles);
        s.frontier_records_max = s.frontier_records_max.max(self.held_records);
        s.frontier_bytes_max = s.frontier_bytes_max.max(self.held_bytes);
        s.open_nodes_max = s.open_nodes_max.max(self.comps.len() as u64);
        let core = summary.anchors.iter().map(|&a| a != u64::MAX).collect();
        self.in_mem.insert(slot);
        self.tiles.insert(
            slot,
            TileState {
                id: summary.tile,
                rect: summary.core,
                name: summary.name.clone(),
                spilled: None,
                summary: Some(summary),
                ids,
                core,
                pending: nodes.len() as u32,
                nodes,
                closed: false,
                waiting: false,
                payload: Some(payload),
            },
        );
        let leaf = self.tiles[&slot]
            .summary
            .as_ref()
            .map(|s| (s.tile, s.core, s.records() as u64));
        if let (Some(e), Some((id, core, records))) = (self.cells.get_mut(&cell), leaf) {
            e.tiles.push(slot);
            e.held += records;
            if id.level > 0 {
                e.rect.get_or_insert_with(|| cell_rect(&id, &core));
                e.arrived.insert((id.level, id.path));
                for up in 1..=id.level {
                    e.ancestors
                        .insert((id.level - up, id.path >> (2 * up as u64)));
                }
                if e.held > TRIM_MIN_RECORDS.max(2 * e.held_after_trim) {
                    self.trim_cell(cell, false);
                }
            }
        }
        // A summary bigger than the whole cap goes to the spill file itself.
        self.spill_over_cap(0)
    }

    /// Moves the oldest in-memory summaries to the spill file until the rest and `incoming`
    /// more bytes fit the cap. (Spilled summaries are not trimmed: records no tile to come can
    /// use are harmless, as matching applies the exact geometry; they only cost disk until
    /// the tile closes.)
    fn spill_over_cap(&mut self, incoming: u64) -> Result<(), StitchError> {
        let Some(sp) = &mut self.spill else {
            return Ok(());
        };
        while self.held_bytes + incoming > self.mem_cap {
            let Some(slot) = self.in_mem.pop_first() else {
                break;
            };
            let Some(t) = self.tiles.get_mut(&slot) else {
                continue;
            };
            let Some(sum) = t.summary.take() else {
                continue;
            };
            let (records, bytes) = (sum.records() as u64, sum.bytes() as u64);
            match sp.write(&sum) {
                Ok(x) => t.spilled = Some((x, records, bytes)),
                Err(e) => {
                    t.summary = Some(sum);
                    return Err(e);
                }
            }
            self.held_bytes -= bytes;
        }
        let s = &mut self.stats;
        s.spilled_summaries = sp.writes;
        s.spill_bytes_written = sp.bytes_written;
        s.spill_reads = sp.reads;
        s.spill_bytes_read = sp.bytes_read;
        s.spill_bytes_max = sp.live_bytes_max;
        Ok(())
    }

    /// Drops the border records of a split cell's open tiles that no tile still to come can
    /// share: a point is needed only while some future tile's zone (core grown by the strip)
    /// can contain it, i.e. while the square of half-width `strip_m` around it reaches
    /// outside the cell (tiles of other cells) or into a part of the cell no arrived leaf
    /// covers (leaves still to come; all of the cell is covered once `complete`). Without
    /// this, a dense cell split into many small leaves held each point once per leaf whose
    /// zone reached it (~7× the cell's points at 6 m leaves) until the whole cell closed —
    /// 700 MB on a simulated drive at a 256 MiB budget. The matches are unchanged: every pair is matched when its second tile arrives, from
    /// records this rule keeps.
    fn trim_cell(&mut self, cell: CellKey, complete: bool) {
        let Some(e) = self.cells.get(&cell) else {
            return;
        };
        let Some(rect) = e.rect else { return };
        let s = self.strip_m + 1e-6;
        let root = (0u8, 0u64);
        let mut dropped_all = 0u64;
        for &slot in &e.tiles {
            let Some(sum) = self.tiles.get_mut(&slot).and_then(|t| t.summary.as_mut()) else {
                continue;
            };
            let before = sum.records();
            // Whether the square of half-width `half` around a record may still meet a tile
            // to come: it reaches outside the cell or into a part no arrived leaf covers.
            let needed = |x: f64, y: f64, half: f64| {
                !rect.expanded(-half).contains(x, y)
                    || (!complete
                        && !e.covered(
                            root,
                            rect,
                            &Rect {
                                x0: x - half,
                                y0: y - half,
                                x1: x + half,
                                y1: y + half,
                            },
                        ))
            };
            // A core (inner) record pairs with any later tile whose zone holds the point; a
            // buffer (outer) record only with the tile whose core holds it.
            let core = sum.core;
            let at = |r: &BorderRecord| (core.x0 + r.dx as f64, core.y0 + r.dy as f64);
            sum.inner.retain(|r| {
                let (x, y) = at(r);
                needed(x, y, s)
            });
            sum.outer.retain(|r| {
                let (x, y) = at(r);
                needed(x, y, 0.0)
            });
            let dropped = before - sum.records();
            if dropped > 0 {
                if dropped * 2 > before {
                    sum.inner.shrink_to_fit();
                    sum.outer.shrink_to_fit();
                }
                self.held_records -= dropped as u64;
                self.held_bytes -= (dropped * std::mem::size_of::<BorderRecord>()) as u64;
                dropped_all += dropped as u64;
            }
        }
        if let Some(e) = self.cells.get_mut(&cell) {
            e.held -= dropped_all;
            e.held_after_trim = e.held;
        }
    }

    /// A worker finished every leaf tile of `cell` (`leaves` of them were sent).
    pub fn cell_done(&mut self, cell: CellKey, leaves: usize) -> Result<(), StitchError> {
        let e = match self.cells.get_mut(&cell) {
            Some(e) if e.released && !e.done => e,
            _ => {
                return Err(StitchError::UnknownCell {
                    tile: format!("(cell completion, {leaves} tiles)"),
                    cell,
                })
            }
        };
        if e.tiles.len() != leaves {
            return Err(StitchError::BadSummary {
                tile: format!("cell {cell:?}"),
                reason: format!(
                    "{leaves} tiles announced, {} arrived before completion",
                    e.tiles.len()
                ),
            });
        }
        e.done = true;
        self.trim_cell(cell, true);
        self.cell_completed(cell);
        Ok(())
    }

    /// Everything was released and processed: closes all remaining tiles. Fails if a cell
    /// never completed (a tile would otherwise be written with wrong ids).
    pub fn finish(&mut self) -> Result<(), StitchError> {
        let mut incomplete: Vec<CellKey> = self
            .cells
            .iter()
            .filter(|(_, e)| !e.done)
            .map(|(k, _)| *k)
            .collect();
        if !incomplete.is_empty() {
            incomplete.sort_unstable();
            return Err(StitchError::Incomplete(incomplete.len(), incomplete[0]));
        }
        let mut keys: Vec<CellKey> = self.cells.keys().copied().collect();
        keys.sort_unstable();
        for k in keys {
            self.try_close(k);
        }
        if let Some(t) = self.tiles.values().next() {
            return Err(StitchError::BadSummary {
                tile: t.name.clone(),
                reason: format!(
                    "{} tile(s) still waiting for final ids at the end of the run",
                    self.tiles.len()
                ),
            });
        }
        Ok(())
    }

    fn cell_completed(&mut self, c: CellKey) {
        self.try_close(c);
        for n in neighbours8(c).collect::<Vec<_>>() {
            self.try_close(n);
        }
    }

    fn try_close(&mut self, c: CellKey) {
        let Some(e) = self.cells.get(&c) else {
            return;
        };
        if !e.released || !e.done || e.closed {
            return;
        }
        if e.relevant
            .iter()
            .any(|d| self.cells.get(d).is_some_and(|d| !d.done))
        {
            return;
        }
        let Some(e) = self.cells.get_mut(&c) else {
            return;
        };
        e.closed = true;
        let tiles = std::mem::take(&mut e.tiles);
        let relevant = std::mem::take(&mut e.relevant);
        for slot in tiles {
            self.close_tile(slot);
        }
        for d in relevant {
            if let Some(de) = self.cells.get_mut(&d) {
                de.refs = de.refs.saturating_sub(1);
            }
            self.maybe_forget(d);
        }
        self.maybe_forget(c);
    }

    fn maybe_forget(&mut self, c: CellKey) {
        if self.cells.get(&c).is_some_and(|e| e.closed && e.refs == 0) {
            self.cells.remove(&c);
        }
    }

    fn close_tile(&mut self, slot: u32) {
        let Some(t) = self.tiles.get_mut(&slot) else {
            return;
        };
        t.closed = true;
        let held = match (t.summary.take(), t.spilled.take()) {
            (Some(s), _) => {
                self.held_bytes -= s.bytes() as u64;
                self.in_mem.remove(&slot);
                Some((s.tile, s.records() as u64))
            }
            (None, Some((x, records, _))) => {
                if let Some(sp) = &mut self.spill {
                    sp.release(x);
                }
                Some((t.id, records))
            }
            _ => None,
        };
        if let Some((id, records)) = held {
            if let Some(e) = self.cells.get_mut(&(id.ix, id.iy)) {
                e.held = e.held.saturating_sub(records);
            }
            self.open_tiles -= 1;
            self.held_records -= records;
        }
        let nodes = std::mem::take(&mut t.nodes);
        for l in nodes {
            if let Some(f) = self.comps.close(node(slot, l)) {
                self.finalise(f);
            }
        }
        self.maybe_ready(slot);
        if let Some(t) = self.tiles.get_mut(&slot) {
            // Still here: some component of this tile can still grow through other tiles.
            t.waiting = true;
            self.waiting += 1;
            self.stats.waiting_tiles_max = self.stats.waiting_tiles_max.max(self.waiting);
        }
    }

    fn finalise(&mut self, f: Final) {
        let id = if f.min_ordinal == u64::MAX {
            0
        } else {
            f.min_ordinal + 1
        };
        if id != 0 {
            // Tiles that write points of the segment (pieces seen only in a buffer do not
            // make a segment cross a border).
            let tiles: HashSet<u32> = f
                .members
                .iter()
                .map(|&m| split(m))
                .filter(|&(slot, label)| {
                    self.tiles
                        .get(&slot)
                        .and_then(|t| t.core.get(label as usize - 1))
                        .copied()
                        .unwrap_or(false)
                })
                .map(|(slot, _)| slot)
                .collect();
            let s = &mut self.stats;
            s.global_segments += 1;
            if tiles.len() >= 2 {
                s.segments_crossing_borders += 1;
            }
            s.max_tiles_per_segment = s.max_tiles_per_segment.max(tiles.len() as u64);
        }
        for m in f.members {
            let (slot, label) = split(m);
            if let Some(t) = self.tiles.get_mut(&slot) {
                if let Some(v) = t.ids.get_mut(label as usize - 1) {
                    *v = id;
                }
                t.pending = t.pending.saturating_sub(1);
            }
            self.maybe_ready(slot);
        }
    }

    fn maybe_ready(&mut self, slot: u32) {
        if !self
            .tiles
            .get(&slot)
            .is_some_and(|t| t.closed && t.pending == 0)
        {
            return;
        }
        if let Some(mut t) = self.tiles.remove(&slot) {
            if t.waiting {
                self.waiting -= 1;
            }
            if let Some(payload) = t.payload.take() {
                self.ready.push(Ready {
                    payload,
                    ids: t.ids,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_rect_walks_back_up_the_quadtree() {
        let cell = Rect {
            x0: 100.0,
            y0: 200.0,
            x1: 150.0,
            y1: 250.0,
        };
        let mut id = TileId::grid(2, 4);
        let mut r = cell;
        for q in [3u8, 0, 2, 1] {
            id = id.child(q);
            r = r.quadrant(q);
            assert_eq!(cell_rect(&id, &r), cell, "{id:?}");
        }
    }

    #[test]
    fn coverage_follows_arrived_leaves() {
        let cell = Rect {
            x0: 0.0,
            y0: 0.0,
            x1: 8.0,
            y1: 8.0,
        };
        let mut e = CellState::default();
        // Leaves: quadrant 0 whole, and quadrant 1 split with only its child 0 arrived.
        for (level, path) in [(1u8, 0u64), (2, 0b01_00)] {
            e.arrived.insert((level, path));
            for up in 1..=level {
                e.ancestors.insert((level - up, path >> (2 * up as u64)));
            }
        }
        let sq = |x: f64, y: f64, s: f64| Rect {
            x0: x - s,
            y0: y - s,
            x1: x + s,
            y1: y + s,
        };
        let root = (0u8, 0u64);
        assert!(e.covered(root, cell, &sq(2.0, 2.0, 1.0)));
        // Reaches from quadrant 0 into the arrived child of quadrant 1 (x 4..6, y 0..2).
        assert!(e.covered(root, cell, &sq(4.0, 1.0, 0.9)));
        // Reaches the missing child 1 of quadrant 1 (x 6..8) or quadrant 2 (y ≥ 4).
        assert!(!e.covered(root, cell, &sq(5.5, 1.0, 1.0)));
        assert!(!e.covered(root, cell, &sq(2.0, 3.5, 1.0)));
    }
}
