//! Spill files: points of tiles that are not complete yet wait on disk, appended through
//! bounded in-memory buffers. A spill record is the point's global id (u64, little endian)
//! followed by its raw LAS record.

use crate::error::{Error, Result};
use crate::model::TileId;
use std::collections::HashMap;
use std::fs::OpenOptions;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

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

/// A small multiplicative hasher for tile ids: the binning loop looks tiles up per point, and
/// SipHash's DoS resistance buys nothing for keys we generate ourselves.
#[derive(Default, Clone, Copy)]
pub struct FastHasher(u64);

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(*b as u64);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
    fn write_u8(&mut self, v: u8) {
        self.write_u64(v as u64);
    }
}

/// HashMap keyed by tile ids with [`FastHasher`].
pub type TileMap<V> = HashMap<TileId, V, BuildHasherDefault<FastHasher>>;

#[derive(Debug, Default)]
struct Slot {
    id: Option<TileId>,
    core: Vec<u8>,
    buf: Vec<u8>,
    /// Points already written to the files (core, buffer).
    flushed: (u64, u64),
    /// Points still in the buffers (core, buffer).
    held: (u64, u64),
    /// Buffer points counted as near the core ([`SpillSet::count_near`]).
    near: u64,
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
        }
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
        v.extend_from_slice(&point_id.to_le_bytes());
        v.extend_from_slice(record);
        *n += 1;
        self.buffered += 8 + record.len();
        if self.buffered > self.limit_bytes {
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
            f.write_all(v).map_err(|e| Error::io(&path, e))?;
            self.buffered -= v.len();
            *flushed += *held;
            *held = 0;
            // Give the memory back: a flushed tile may receive few more points.
            *v = Vec::new();
        }
        Ok(())
    }

    fn relieve(&mut self) -> Result<()> {
        let mut sizes: Vec<(usize, usize)> = self
            .slots
            .iter()
            .enumerate()
            .filter(|(_, s)| s.id.is_some())
            .map(|(i, s)| (s.core.len() + s.buf.len(), i))
            .collect();
        sizes.sort_by(|a, b| b.cmp(a));
        for (_, i) in sizes {
            if self.buffered <= self.limit_bytes / 2 {
                break;
            }
            self.flush_slot(i)?;
        }
        Ok(())
    }

    /// Flushes a tile's buffers and returns its (core, buffer) point counts; the tile's spill
    /// files are then complete and belong to the caller.
    pub fn finish(&mut self, id: TileId) -> Result<SpillCounts> {
        let Some(slot) = self.index.remove(&id) else {
            return Ok(SpillCounts::default());
        };
        self.flush_slot(slot)?;
        let s = std::mem::take(&mut self.slots[slot]);
        self.free.push(slot);
        Ok(SpillCounts {
            core: s.flushed.0,
            buf: s.flushed.1,
            near: s.near,
        })
    }

    /// Counts one buffer point of a slot as lying within the near distance of its core (the
    /// stages' widest bounded context), for the memory plan.
    #[inline]
    pub fn count_near(&mut self, slot: usize) {
        self.slots[slot].near += 1;
    }
}

/// Points written to a tile's spill files.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpillCounts {
    /// Core points.
    pub core: u64,
    /// Buffer points.
    pub buf: u64,
    /// Buffer points counted near the core ([`SpillSet::count_near`]).
    pub near: u64,
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
