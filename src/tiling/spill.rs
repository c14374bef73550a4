//! Spill files: points of tiles that are not complete yet wait on disk, appended through
//! bounded in-memory buffers. A spill record is the point's global id (u64, little endian)
//! followed by its raw LAS record.
//!
//! When a tile is released, what is still in its buffers can be handed to the worker in memory
//! (a [`MemTail`] after the file's points) instead of being written and read straight back;
//! those tails stay charged to the same bound until the worker drops them.

use crate::error::{Error, Result};
use crate::model::TileId;
use std::collections::HashMap;
use std::fs::OpenOptions;
use std::hash::BuildHasherDefault;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Which of a tile's two spill files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Part {
    /// Points whose core tile this is.
    Core,
    /// Buffer-zone points (context only).
    Buffer,
}

/// Path of a tile's spill file.
pub fn spill_path(dir: &Path, id: TileId, part: Part) -> PathBuf {
    let ext = match part {
        Part::Core => "core",
        Part::Buffer => "buf",
    };
    dir.join(format!(
        "{}_{}_{}_{:x}.{ext}",
        id.ix, id.iy, id.level, id.path
    ))
}

pub use crate::rng::FastHasher;

/// HashMap keyed by tile ids with [`FastHasher`].
pub type TileMap<V> = HashMap<TileId, V, BuildHasherDefault<FastHasher>>;

/// Capacity of a full buffer block, bytes.
const BLOCK: usize = 256 << 10;
/// Capacity of a part's first block, bytes: it doubles up to [`BLOCK`], so the many tiles that
/// receive few points do not each hold a whole block. The bound charges capacity, first blocks
/// included: a region read in no spatial order holds one per part in every cell, and flushes
/// small parts more often rather than grow past its bound.
const FIRST_BLOCK: usize = 2 << 10;

/// The buffered records of one slot part, in blocks holding whole records. Appending never
/// moves buffered bytes (a growing `Vec` would copy them at every doubling), and flushed
/// full blocks go back to the set's pool instead of being freed and faulted in again.
#[derive(Debug, Default)]
struct Blocks {
    list: Vec<Vec<u8>>,
    len: usize,
    /// Capacity of the blocks: what the set charges to its bound (a part's first block
    /// holds a few records in a larger capacity, and a region of many open cells read in no
    /// spatial order holds one per part and cell).
    cap: usize,
}

impl Blocks {
    #[inline]
    fn push(&mut self, point_id: u64, record: &[u8], pool: &mut Vec<Vec<u8>>) {
        let need = 8 + record.len();
        let b = match self.list.last_mut() {
            Some(b) if b.capacity() - b.len() >= need => b,
            _ => self.grow(need, pool),
        };
        b.extend_from_slice(&point_id.to_le_bytes());
        b.extend_from_slice(record);
        self.len += need;
    }

    #[cold]
    fn grow(&mut self, need: usize, pool: &mut Vec<Vec<u8>>) -> &mut Vec<u8> {
        let first = self.list.len() == 1 && self.list[0].capacity() < BLOCK;
        if first {
            let b = &mut self.list[0];
            let before = b.capacity();
            let cap = (2 * b.capacity()).clamp(b.len() + need, BLOCK.max(b.len() + need));
            b.reserve_exact(cap - b.len());
            self.cap += b.capacity() - before;
        } else {
            let b = match (self.list.is_empty(), pool.pop()) {
                (false, Some(b)) => b,
                (empty, spare) => {
                    // A first block from the pool would pin a whole block to a tile that may
                    // get few points: keep the spare for a later full block.
                    if let Some(b) = spare {
                        pool.push(b);
                    }
                    let cap = if empty { FIRST_BLOCK } else { BLOCK };
                    Vec::with_capacity(cap.max(need))
                }
            };
            self.cap += b.capacity();
            self.list.push(b);
        }
        let last = self.list.len() - 1;
        &mut self.list[last]
    }
}

#[derive(Debug, Default)]
struct Slot {
    id: Option<TileId>,
    core: Blocks,
    buf: Blocks,
    /// Points already written to the files (core, buffer).
    flushed: (u64, u64),
    /// Points still in the buffers (core, buffer).
    held: (u64, u64),
    /// Buffer points counted as near the core ([`SpillSet::count_near`]).
    near: u64,
    /// Buffer points counted in the zone far thinning keeps whole ([`SpillSet::count_kept`]).
    kept: u64,
}

/// A set of append-only spill files with one shared bound on buffered bytes. When the bound is
/// exceeded, the largest buffers are flushed until half of it is free, so big contiguous
/// writes dominate and at most one file handle is open at a time.
#[derive(Debug)]
pub struct SpillSet {
    dir: PathBuf,
    limit_bytes: usize,
    buffered: usize,
    slots: Vec<Slot>,
    free: Vec<usize>,
    index: TileMap<usize>,
    /// Hand released tiles' buffers over in memory ([`SpillSet::with_handoff`]).
    handoff: bool,
    /// Bytes of handed-over tails not dropped yet (shared with their holders).
    outstanding: Arc<AtomicUsize>,
    /// Empty full-size blocks kept for reuse, at most `limit_bytes / 8` bytes on top of the
    /// bound (a pool as large as the bound measured no faster and raised peak RSS by 30 MiB).
    pool: Vec<Vec<u8>>,
}

impl SpillSet {
    /// Creates a spill set writing into `dir` (which must exist).
    pub fn new(dir: &Path, limit_bytes: usize) -> Self {
        SpillSet {
            dir: dir.to_path_buf(),
            limit_bytes: limit_bytes.max(1 << 16),
            buffered: 0,
            slots: Vec::new(),
            free: Vec::new(),
            index: TileMap::default(),
            handoff: false,
            outstanding: Arc::new(AtomicUsize::new(0)),
            pool: Vec::new(),
        }
    }

    /// Like [`SpillSet::new`], but [`SpillSet::finish`] hands a released tile's buffered
    /// points over in memory while the tails not yet dropped take at most half the bound; the
    /// bound then covers buffers plus those tails. Half, so that flushing can always free a
    /// large share of the bound at once (a bound filled by tails would force a flush per
    /// point). Worth it where the holder loads the tile soon (the pipeline's workers), not
    /// where it waits behind other work (split children).
    pub fn with_handoff(dir: &Path, limit_bytes: usize) -> Self {
        SpillSet {
            handoff: true,
            ..Self::new(dir, limit_bytes)
        }
    }

    /// Bytes held: buffered points plus handed-over tails not dropped yet.
    pub fn held_bytes(&self) -> usize {
        self.buffered + self.outstanding.load(Ordering::Relaxed)
    }

    /// The slot of a tile, created on first use. Slots stay valid until [`SpillSet::finish`].
    pub fn slot(&mut self, id: TileId) -> usize {
        if let Some(s) = self.index.get(&id) {
            return *s;
        }
        let s = self.free.pop().unwrap_or_else(|| {
            self.slots.push(Slot::default());
            self.slots.len() - 1
        });
        self.slots[s].id = Some(id);
        self.index.insert(id, s);
        s
    }

    /// Appends one point to a slot.
    #[inline]
    pub fn push(&mut self, slot: usize, part: Part, point_id: u64, record: &[u8]) -> Result<()> {
        let s = &mut self.slots[slot];
        let (v, n) = match part {
            Part::Core => (&mut s.core, &mut s.held.0),
            Part::Buffer => (&mut s.buf, &mut s.held.1),
        };
        let before = v.cap;
        v.push(point_id, record, &mut self.pool);
        *n += 1;
        self.buffered += v.cap - before;
        if self.held_bytes() > self.limit_bytes {
            self.relieve()?;
        }
        Ok(())
    }

    fn flush_slot(&mut self, slot: usize) -> Result<()> {
        let s = &mut self.slots[slot];
        let Some(id) = s.id else { return Ok(()) };
        for part in [Part::Core, Part::Buffer] {
            let (v, held, flushed) = match part {
                Part::Core => (&mut s.core, &mut s.held.0, &mut s.flushed.0),
                Part::Buffer => (&mut s.buf, &mut s.held.1, &mut s.flushed.1),
            };
            if *held == 0 {
                continue;
            }
            let path = spill_path(&self.dir, id, part);
            let mut f = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .map_err(|e| Error::io(&path, e))?;
            for b in &v.list {
                f.write_all(b).map_err(|e| Error::io(&path, e))?;
            }
            self.buffered -= v.cap;
            *flushed += *held;
            *held = 0;
            // Full blocks are kept for reuse up to the pool's share; the rest of the memory
            // goes back (a flushed tile may receive few more points).
            let mut pooled: usize = self.pool.iter().map(|b| b.capacity()).sum();
            for mut b in std::mem::take(v).list {
                if b.capacity() >= BLOCK && pooled + b.capacity() <= self.limit_bytes / 8 {
                    pooled += b.capacity();
                    b.clear();
                    self.pool.push(b);
                }
            }
        }
        Ok(())
    }

    fn relieve(&mut self) -> Result<()> {
        let mut sizes: Vec<(usize, usize)> = self
            .slots
            .iter()
            .enumerate()
            .filter(|(_, s)| s.id.is_some())
            .map(|(i, s)| (s.core.cap + s.buf.cap, i))
            .collect();
        sizes.sort_by(|a, b| b.cmp(a));
        for (_, i) in sizes {
            if self.held_bytes() <= self.limit_bytes / 2 {
                break;
            }
            self.flush_slot(i)?;
        }
        Ok(())
    }

    /// Completes a tile: its points are then in its two parts (spill file, then an in-memory
    /// tail when handed over), which belong to the caller.
    pub fn finish(&mut self, id: TileId) -> Result<FinishedTile> {
        let Some(slot) = self.index.remove(&id) else {
            return Ok(FinishedTile {
                core: SpillPart::empty(spill_path(&self.dir, id, Part::Core)),
                buf: SpillPart::empty(spill_path(&self.dir, id, Part::Buffer)),
                near: 0,
                kept: 0,
            });
        };
        let held = self.slots[slot].core.cap + self.slots[slot].buf.cap;
        let hand =
            self.handoff && self.outstanding.load(Ordering::Relaxed) + held <= self.limit_bytes / 2;
        if hand {
            self.buffered -= held;
            self.outstanding.fetch_add(held, Ordering::Relaxed);
        } else {
            self.flush_slot(slot)?;
        }
        let s = std::mem::take(&mut self.slots[slot]);
        self.free.push(slot);
        let part = |p: Part, on_disk: u64, held: u64, bytes: Blocks| SpillPart {
            path: spill_path(&self.dir, id, p),
            on_disk,
            tail: (held > 0).then(|| MemTail {
                points: held,
                bytes: bytes.cap,
                blocks: bytes.list,
                outstanding: self.outstanding.clone(),
            }),
        };
        Ok(FinishedTile {
            core: part(Part::Core, s.flushed.0, s.held.0, s.core),
            buf: part(Part::Buffer, s.flushed.1, s.held.1, s.buf),
            near: s.near,
            kept: s.kept,
        })
    }

    /// Counts one buffer point of a slot as lying within the near distance of its core (the
    /// stages' widest bounded context), for the memory plan.
    #[inline]
    pub fn count_near(&mut self, slot: usize) {
        self.slots[slot].near += 1;
    }

    /// Counts one buffer point of a slot as lying within the zone the far-buffer thinning
    /// keeps whole (`tiling::FarThin::count_m`), for the memory plan.
    #[inline]
    pub fn count_kept(&mut self, slot: usize) {
        self.slots[slot].kept += 1;
    }
}

/// A completed tile's two parts and its near count.
#[derive(Debug)]
pub struct FinishedTile {
    /// Core points.
    pub core: SpillPart,
    /// Buffer points.
    pub buf: SpillPart,
    /// Buffer points counted near the core ([`SpillSet::count_near`]).
    pub near: u64,
    /// Buffer points counted in the zone kept whole ([`SpillSet::count_kept`]).
    pub kept: u64,
}

/// Records handed over in memory (spill record format), charged to their spill set's bound
/// until dropped.
#[derive(Debug)]
pub struct MemTail {
    points: u64,
    bytes: usize,
    blocks: Vec<Vec<u8>>,
    outstanding: Arc<AtomicUsize>,
}

impl Drop for MemTail {
    fn drop(&mut self) {
        self.outstanding.fetch_sub(self.bytes, Ordering::Relaxed);
    }
}

/// The core or buffer points of a complete tile: `on_disk` points in the spill file at
/// `path`, then the in-memory tail, if any.
#[derive(Debug)]
pub struct SpillPart {
    /// Spill file (may not exist when nothing was flushed).
    pub path: PathBuf,
    /// Points in the file.
    pub on_disk: u64,
    tail: Option<MemTail>,
}

impl SpillPart {
    /// A part held entirely in the file at `path` (which may not exist when empty).
    pub fn empty(path: PathBuf) -> Self {
        SpillPart {
            path,
            on_disk: 0,
            tail: None,
        }
    }

    /// Points in the part.
    pub fn points(&self) -> u64 {
        self.on_disk + self.tail.as_ref().map_or(0, |t| t.points)
    }

    /// Streams the part's points in order (file first, then tail), calling `f(id, record)`.
    pub fn for_each(
        &self,
        record_len: usize,
        block_points: usize,
        mut f: impl FnMut(u64, &[u8]) -> Result<()>,
    ) -> Result<()> {
        for_each_spilled(&self.path, record_len, self.on_disk, block_points, &mut f)?;
        for b in self.tail.iter().flat_map(|t| &t.blocks) {
            for rec in b.chunks_exact(8 + record_len) {
                let mut id = [0u8; 8];
                id.copy_from_slice(&rec[..8]);
                f(u64::from_le_bytes(id), &rec[8..])?;
            }
        }
        Ok(())
    }

    /// Deletes the spill file and frees the tail.
    pub fn release(&mut self) {
        let _ = std::fs::remove_file(&self.path);
        self.tail = None;
    }
}

/// Streams a spill file in blocks of at most `block_points`, calling `f(id, record)`.
pub fn for_each_spilled(
    path: &Path,
    record_len: usize,
    expected: u64,
    block_points: usize,
    mut f: impl FnMut(u64, &[u8]) -> Result<()>,
) -> Result<()> {
    if expected == 0 {
        return Ok(());
    }
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let stride = 8 + record_len;
    let mut buf = vec![0u8; stride * block_points.max(1)];
    let mut left = expected;
    while left > 0 {
        let n = (left as usize).min(block_points.max(1));
        let bytes = &mut buf[..n * stride];
        file.read_exact(bytes).map_err(|e| Error::io(path, e))?;
        for rec in bytes.chunks_exact(stride) {
            let mut id = [0u8; 8];
            id.copy_from_slice(&rec[..8]);
            f(u64::from_le_bytes(id), &rec[8..])?;
        }
        left -= n as u64;
    }
    let mut probe = [0u8; 1];
    if file.read(&mut probe).map_err(|e| Error::io(path, e))? != 0 {
        return Err(Error::Internal(format!(
            "spill file {} holds more than the {expected} points counted",
            path.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(i: u64, len: usize) -> Vec<u8> {
        (0..len)
            .map(|k| (i.wrapping_mul(31) as usize + k) as u8)
            .collect()
    }

    /// Points as (id, record), in order.
    type Points = Vec<(u64, Vec<u8>)>;

    fn read(part: &SpillPart, len: usize) -> Points {
        let mut v = Vec::new();
        part.for_each(len, 1000, |id, rec| {
            v.push((id, rec.to_vec()));
            Ok(())
        })
        .unwrap();
        v
    }

    /// Points come back in push order from file + tail, whether a tile was flushed, handed
    /// over or both, and buffers plus outstanding tails never exceed the bound.
    #[test]
    fn handoff_keeps_order_and_bound() {
        let dir = tempfile::tempdir().unwrap();
        let len = 20;
        let limit = 1 << 16;
        let mut set = SpillSet::with_handoff(dir.path(), limit);
        let tiles: Vec<TileId> = (0..4).map(|i| TileId::grid(i, 0)).collect();
        let mut expect: Vec<[Points; 2]> = vec![Default::default(); 4];
        let mut rng = crate::rng::Rng(7);
        let mut held = Vec::new();
        let mut tails = 0;
        for i in 0..40_000u64 {
            // Tiles 0 and 1 close half-way; 2 and 3 keep receiving points.
            let t = if i < 20_000 {
                (rng.u() * 4.0) as usize
            } else {
                2 + (rng.u() * 2.0) as usize
            };
            if i == 20_000 {
                for t in [0, 1] {
                    let done = set.finish(tiles[t]).unwrap();
                    tails += [&done.core, &done.buf]
                        .iter()
                        .filter(|p| p.tail.is_some())
                        .count();
                    held.push((t, done));
                }
            }
            let part = if rng.u() < 0.3 {
                Part::Buffer
            } else {
                Part::Core
            };
            let slot = set.slot(tiles[t]);
            let rec = record(i, len);
            set.push(slot, part, i, &rec).unwrap();
            expect[t][(part == Part::Buffer) as usize].push((i, rec));
            assert!(set.held_bytes() <= limit, "{} > {limit}", set.held_bytes());
        }
        assert!(tails > 0, "no tile was handed over in memory");
        for t in [2, 3] {
            held.push((t, set.finish(tiles[t]).unwrap()));
        }
        for (t, done) in &held {
            assert_eq!(read(&done.core, len), expect[*t][0], "tile {t} core");
            assert_eq!(read(&done.buf, len), expect[*t][1], "tile {t} buffer");
            assert_eq!(done.core.points(), expect[*t][0].len() as u64);
        }
        drop(held);
        assert_eq!(set.held_bytes(), 0);
    }

    /// A part bigger than one block is held in several blocks and read back in order; without
    /// hand-over the same points come back from the file.
    #[test]
    fn blocks_hold_many_records() {
        let dir = tempfile::tempdir().unwrap();
        let len = 36;
        for handoff in [true, false] {
            let mut set = if handoff {
                SpillSet::with_handoff(dir.path(), 16 << 20)
            } else {
                SpillSet::new(dir.path(), 16 << 20)
            };
            let id = TileId::grid(handoff as i64, 5);
            let slot = set.slot(id);
            let n = 3 * BLOCK / (8 + len) + 17;
            let mut expect = Vec::new();
            for i in 0..n as u64 {
                let rec = record(i, len);
                set.push(slot, Part::Core, i, &rec).unwrap();
                expect.push((i, rec));
            }
            let done = set.finish(id).unwrap();
            assert_eq!(done.core.tail.is_some(), handoff);
            assert_eq!(done.core.on_disk, if handoff { 0 } else { n as u64 });
            if let Some(t) = &done.core.tail {
                assert!(t.blocks.len() >= 3, "{} blocks", t.blocks.len());
            }
            assert_eq!(read(&done.core, len), expect);
            assert_eq!(done.buf.points(), 0);
        }
    }
}
