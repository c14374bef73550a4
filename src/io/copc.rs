//! COPC tiles (Cloud Optimized Point Cloud, copc.io 1.0): a LAS 1.4 LAZ file (point format 6,
//! 7 or 8) whose compressed chunks are the nodes of an octree, described by a hierarchy EVLR,
//! so viewers (QGIS ≥ 3.26, Potree, PDAL, laspy's `CopcReader`) read a region or a level of
//! detail without decoding the whole file. Any LAS reader still reads it as plain LAZ: the
//! chunk table lists the nodes' chunks with their point counts.
//!
//! The octree is built per tile from the tile's records (already in memory, or memory-mapped
//! from the stitching spill): a node keeps the first point of each occupied cell of a
//! [`GRID`]³ grid over its cube (the level-of-detail sample; the node's spacing is its side /
//! [`GRID`], the usual COPC convention) and hands the others to its eight children, until a
//! node holds at most [`MAX_NODE_POINTS`]. Extra memory: 9 bytes per point (the permutation,
//! its scratch copy and a bucket byte), a 256 KiB cell bitmap and one node's records.
//!
//! Every point lies inside its node's cube as readers compute it (`min + key · side`, with
//! `side = (max − min) / 2^level` in `f64`): splits compare against exactly those
//! boundaries, so a bounds query that selects nodes by overlap misses no point.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

/// Cells per node side of the level-of-detail sample.
pub const GRID: usize = 128;
/// A node with more points than this is split (its sample stays, the rest go to children).
pub const MAX_NODE_POINTS: usize = 100_000;
/// Deepest level: below it nodes keep all their points (only many copies of one location
/// get this deep: level 20 of a 1 km cube is a 1 mm node).
const MAX_LEVEL: i32 = 20;
/// User id of the COPC records.
pub const USER_ID: &str = "copc";
/// Size of the COPC info VLR's data.
const INFO_LEN: usize = 160;
/// Byte offsets in a LAS 1.4 header.
const HEADER_LEN: u64 = 375;

/// One octree node: `key` = (level, x, y, z) and the range of the permutation it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Node {
    /// Level, x, y, z (the COPC voxel key).
    pub key: [i32; 4],
    start: usize,
    /// Points of the node.
    pub len: usize,
}

/// The octree of one tile: the root cube and the nodes, each a range of `order`.
#[derive(Debug)]
pub struct Octree {
    /// Centre of the root cube.
    pub center: [f64; 3],
    /// Half the side of the root cube.
    pub halfsize: f64,
    /// Nodes in file order (level by level).
    pub nodes: Vec<Node>,
    order: Vec<u32>,
    /// Smallest and largest integer X, Y, Z of the records.
    pub extent: ([i32; 3], [i32; 3]),
}

impl Octree {
    /// Record indices of `node`.
    pub fn points(&self, node: &Node) -> &[u32] {
        &self.order[node.start..node.start + node.len]
    }

    /// Min and max corners of the root cube, as readers compute them.
    pub fn root(&self) -> ([f64; 3], [f64; 3]) {
        let c = self.center;
        let h = self.halfsize;
        (
            [c[0] - h, c[1] - h, c[2] - h],
            [c[0] + h, c[1] + h, c[2] + h],
        )
    }

    /// Bounds of a node (min, max) as readers compute them.
    pub fn node_bounds(&self, key: [i32; 4]) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.root();
        let mut a = [0.0; 3];
        let mut b = [0.0; 3];
        for k in 0..3 {
            let side = (hi[k] - lo[k]) / f64::powi(2.0, key[0]);
            a[k] = lo[k] + f64::from(key[k + 1]) * side;
            b[k] = lo[k] + f64::from(key[k + 1] + 1) * side;
        }
        (a, b)
    }

    /// Builds the octree of `records` (length `rl` each; X, Y, Z the first three i32).
    pub fn build(records: &[u8], rl: usize, t: &las::Vector<las::Transform>) -> Octree {
        let n = records.len() / rl;
        let int = |i: usize, k: usize| {
            let o = i * rl + 4 * k;
            i32::from_le_bytes([records[o], records[o + 1], records[o + 2], records[o + 3]])
        };
        let tr = [t.x, t.y, t.z];
        let real = |i: usize, k: usize| f64::from(int(i, k)) * tr[k].scale + tr[k].offset;
        let mut lo = [i32::MAX; 3];
        let mut hi = [i32::MIN; 3];
        for i in 0..n {
            for k in 0..3 {
                let v = int(i, k);
                lo[k] = lo[k].min(v);
                hi[k] = hi[k].max(v);
            }
        }
        if n == 0 {
            lo = [0; 3];
            hi = [0; 3];
        }
        let at = |v: i32, k: usize| f64::from(v) * tr[k].scale + tr[k].offset;
        let mut center = [0.0; 3];
        let mut halfsize: f64 = 0.0;
        let mut pad: f64 = 0.0;
        for k in 0..3 {
            let (a, b) = (at(lo[k], k), at(hi[k], k));
            center[k] = 0.5 * (a + b);
            halfsize = halfsize.max(0.5 * (b - a));
            pad = pad.max(tr[k].scale.abs());
        }
        // Padded by one scale step so no point sits on the root's faces after rounding.
        halfsize = halfsize * (1.0 + 1e-9) + pad;
        let mut tree = Octree {
            center,
            halfsize,
            nodes: Vec::new(),
            order: (0..n as u32).collect(),
            extent: (lo, hi),
        };
        let (rlo, rhi) = tree.root();
        let mut scratch = vec![0u32; n];
        let mut cells = vec![0u64; GRID * GRID * GRID / 64];
        let mut queue = std::collections::VecDeque::from([([0i32, 0, 0, 0], 0usize, n)]);
        while let Some((key, start, len)) = queue.pop_front() {
            if len <= MAX_NODE_POINTS || key[0] >= MAX_LEVEL {
                tree.nodes.push(Node { key, start, len });
                continue;
            }
            let level = key[0];
            let mut min = [0.0; 3];
            let mut cell = [0.0; 3];
            let mut mid = [0.0; 3];
            for k in 0..3 {
                let side = (rhi[k] - rlo[k]) / f64::powi(2.0, level);
                let half = (rhi[k] - rlo[k]) / f64::powi(2.0, level + 1);
                min[k] = rlo[k] + f64::from(key[k + 1]) * side;
                mid[k] = rlo[k] + f64::from(2 * key[k + 1] + 1) * half;
                cell[k] = side / GRID as f64;
            }
            // Bucket 0: the sample this node keeps; 1 + octant: the children's points.
            let mut bucket = vec![0u8; len];
            let mut counts = [0usize; 9];
            let mut set = Vec::new();
            for (j, &i) in tree.order[start..start + len].iter().enumerate() {
                let i = i as usize;
                let p = [real(i, 0), real(i, 1), real(i, 2)];
                let mut id = 0usize;
                for k in 0..3 {
                    let c = ((p[k] - min[k]) / cell[k]).floor();
                    id = id * GRID + (c.max(0.0) as usize).min(GRID - 1);
                }
                let b = if cells[id / 64] & (1 << (id % 64)) == 0 {
                    cells[id / 64] |= 1 << (id % 64);
                    set.push(id);
                    0
                } else {
                    let o = usize::from(p[0] >= mid[0])
                        | usize::from(p[1] >= mid[1]) << 1
                        | usize::from(p[2] >= mid[2]) << 2;
                    1 + o
                };
                bucket[j] = b as u8;
                counts[b] += 1;
            }
            for id in set {
                cells[id / 64] = 0;
            }
            let mut first = [0usize; 9];
            for b in 1..9 {
                first[b] = first[b - 1] + counts[b - 1];
            }
            let mut next = first;
            for (j, &i) in tree.order[start..start + len].iter().enumerate() {
                let b = bucket[j] as usize;
                scratch[next[b]] = i;
                next[b] += 1;
            }
            tree.order[start..start + len].copy_from_slice(&scratch[..len]);
            tree.nodes.push(Node {
                key,
                start,
                len: counts[0],
            });
            for o in 0..8 {
                if counts[o + 1] > 0 {
                    let child = [
                        level + 1,
                        2 * key[1] + (o & 1) as i32,
                        2 * key[2] + ((o >> 1) & 1) as i32,
                        2 * key[3] + ((o >> 2) & 1) as i32,
                    ];
                    queue.push_back((child, start + first[o + 1], counts[o + 1]));
                }
            }
        }
        tree
    }
}

/// Per-file figures the header needs: points by return and the GPS time range.
struct Stats {
    by_return: [u64; 15],
    gps: (f64, f64),
}

fn stats(records: &[u8], rl: usize) -> Stats {
    let mut s = Stats {
        by_return: [0; 15],
        gps: (f64::INFINITY, f64::NEG_INFINITY),
    };
    for r in records.chunks_exact(rl) {
        let ret = usize::from(r[14] & 0x0F);
        if (1..=15).contains(&ret) {
            s.by_return[ret - 1] += 1;
        }
        let t = f64::from_le_bytes(r[22..30].try_into().unwrap_or([0; 8]));
        if t.is_finite() {
            s.gps.0 = s.gps.0.min(t);
            s.gps.1 = s.gps.1.max(t);
        }
    }
    if s.gps.0 > s.gps.1 {
        s.gps = (0.0, 0.0);
    }
    s
}

/// Where the hierarchy ended up: (start of the first EVLR, root page offset, page size).
#[derive(Default, Clone, Copy)]
struct Placement {
    evlr_start: u64,
    page_offset: u64,
    page_size: u64,
}

/// Header, COPC info VLR, the template's other VLRs and the laszip VLR, as bytes.
fn head_bytes(
    header: &las::Header,
    tree: &Octree,
    stats: &Stats,
    spacing: f64,
    laz_vlr: &laz::LazVlr,
    at: Placement,
    evlrs: u32,
) -> Result<Vec<u8>> {
    let bad = |e: las::Error| Error::Internal(format!("COPC header: {e}"));
    let mut info = Vec::with_capacity(INFO_LEN);
    for v in [
        tree.center[0],
        tree.center[1],
        tree.center[2],
        tree.halfsize,
        spacing,
    ] {
        info.extend(v.to_le_bytes());
    }
    info.extend(at.page_offset.to_le_bytes());
    info.extend(at.page_size.to_le_bytes());
    info.extend(stats.gps.0.to_le_bytes());
    info.extend(stats.gps.1.to_le_bytes());
    info.resize(INFO_LEN, 0);
    let mut laz_data = Vec::new();
    laz_vlr
        .write_to(&mut laz_data)
        .map_err(|e| Error::Internal(format!("COPC laszip VLR: {e}")))?;
    let mut vlrs = vec![las::Vlr {
        user_id: USER_ID.into(),
        record_id: 1,
        description: "COPC info".into(),
        data: info,
    }];
    vlrs.extend(
        header
            .vlrs()
            .iter()
            .filter(|v| !las::laz::is_laszip_vlr(v) && v.user_id != USER_ID)
            .cloned(),
    );
    vlrs.push(las::Vlr {
        user_id: "laszip encoded".into(),
        record_id: 22204,
        description: "laz variable chunks".into(),
        data: laz_data,
    });
    let mut raw = header.clone().into_raw().map_err(bad)?;
    let n = tree.order.len() as u64;
    let t = header.transforms();
    let tr = [t.x, t.y, t.z];
    let (lo, hi) = tree.extent;
    let real = |v: i32, k: usize| f64::from(v) * tr[k].scale + tr[k].offset;
    raw.version = las::Version::new(1, 4);
    raw.header_size = HEADER_LEN as u16;
    raw.point_data_record_format |= 0x80;
    raw.global_encoding |= 16; // WKT (required with formats 6–10)
    raw.number_of_point_records = 0; // legacy fields are 0 for formats 6–10 (LAS 1.4 R15)
    raw.number_of_points_by_return = [0; 5];
    [raw.max_x, raw.min_x] = [real(hi[0], 0), real(lo[0], 0)];
    [raw.max_y, raw.min_y] = [real(hi[1], 1), real(lo[1], 1)];
    [raw.max_z, raw.min_z] = [real(hi[2], 2), real(lo[2], 2)];
    raw.start_of_waveform_data_packet_record = Some(0);
    raw.evlr = Some(las::raw::header::Evlr {
        start_of_first_evlr: at.evlr_start,
        number_of_evlrs: evlrs,
    });
    raw.large_file = Some(las::raw::header::LargeFile {
        number_of_point_records: n,
        number_of_points_by_return: stats.by_return,
    });
    raw.padding.clear();
    raw.number_of_variable_length_records = vlrs.len() as u32;
    let vlr_len: usize = vlrs.iter().map(|v| v.len(false)).sum();
    raw.offset_to_point_data = u32::try_from(HEADER_LEN as usize + vlr_len)
        .map_err(|_| Error::Internal("COPC header: VLRs too large".into()))?;
    let mut out = Vec::with_capacity(raw.offset_to_point_data as usize);
    raw.write_to(&mut out).map_err(bad)?;
    for v in vlrs {
        v.into_raw(false)
            .and_then(|r| r.write_to(&mut out))
            .map_err(bad)?;
    }
    debug_assert_eq!(out.len(), raw.offset_to_point_data as usize);
    Ok(out)
}

/// Writes `records` (the format of `header`: 6, 7 or 8, with its extra bytes) to `path` as
/// a COPC file. `edit` is applied to each record as it is written (it may change extra bytes
/// only: the octree, bounds and statistics come from `records` as given); `observe` sees
/// each node's records as written.
pub fn write(
    path: &Path,
    header: &las::Header,
    records: &[u8],
    edit: &dyn Fn(&mut [u8]) -> Result<()>,
    observe: &mut dyn FnMut(&[u8]) -> Result<()>,
) -> Result<()> {
    let fmt = *header.point_format();
    let id = fmt.to_u8().unwrap_or(255);
    if !(6..=8).contains(&id) {
        return Err(Error::Internal(format!(
            "{}: COPC holds point formats 6, 7 and 8, not {id}",
            path.display()
        )));
    }
    let rl = usize::from(fmt.len());
    if !records.len().is_multiple_of(rl) {
        return Err(Error::Internal(format!(
            "{}: {} record bytes are not a multiple of {rl}",
            path.display(),
            records.len()
        )));
    }
    let io = |e: std::io::Error| Error::io(path, e);
    let tree = Octree::build(records, rl, header.transforms());
    let st = stats(records, rl);
    let spacing = 2.0 * tree.halfsize / GRID as f64;
    let items = laz::LazItemRecordBuilder::default_for_point_format_id(id, fmt.extra_bytes)
        .map_err(|e| Error::Internal(format!("COPC laz items: {e}")))?;
    let laz_vlr = laz::LazVlrBuilder::new(items)
        .with_variable_chunk_size()
        .build();
    let extra_evlrs: Vec<las::Vlr> = header
        .evlrs()
        .iter()
        .filter(|v| v.user_id != USER_ID)
        .cloned()
        .collect();
    let evlrs = 1 + extra_evlrs.len() as u32;
    let head = head_bytes(
        header,
        &tree,
        &st,
        spacing,
        &laz_vlr,
        Placement::default(),
        evlrs,
    )?;
    let file = File::create(path).map_err(io)?;
    let mut out = BufWriter::with_capacity(1 << 20, file);
    out.write_all(&head).map_err(io)?;
    let mut comp = laz::LasZipCompressor::new(out, laz_vlr.clone())
        .map_err(|e| Error::Internal(format!("{}: {e}", path.display())))?;
    comp.reserve_offset_to_chunk_table().map_err(io)?;
    // (key, offset, bytes, points) of every node.
    let mut entries: Vec<([i32; 4], u64, u64, usize)> = Vec::with_capacity(tree.nodes.len());
    let mut buf = Vec::new();
    for node in &tree.nodes {
        let start = comp.get_mut().stream_position().map_err(io)?;
        buf.clear();
        for &i in tree.points(node) {
            let i = i as usize;
            buf.extend_from_slice(&records[i * rl..(i + 1) * rl]);
            let n = buf.len();
            edit(&mut buf[n - rl..])?;
        }
        observe(&buf)?;
        comp.compress_many(&buf).map_err(io)?;
        comp.finish_current_chunk().map_err(io)?;
        let end = comp.get_mut().stream_position().map_err(io)?;
        entries.push((node.key, start, end - start, node.len));
    }
    comp.done().map_err(io)?;
    let mut out = comp.into_inner();
    let evlr_start = out.seek(SeekFrom::End(0)).map_err(io)?;
    let mut page = Vec::with_capacity(entries.len() * 32);
    for (key, offset, bytes, points) in &entries {
        for v in key {
            page.extend(v.to_le_bytes());
        }
        page.extend(offset.to_le_bytes());
        let too_big = || Error::Internal(format!("{}: COPC node too large", path.display()));
        page.extend(i32::try_from(*bytes).map_err(|_| too_big())?.to_le_bytes());
        page.extend(i32::try_from(*points).map_err(|_| too_big())?.to_le_bytes());
    }
    let placement = Placement {
        evlr_start,
        page_offset: evlr_start + 60,
        page_size: page.len() as u64,
    };
    let hierarchy = las::Vlr {
        user_id: USER_ID.into(),
        record_id: 1000,
        description: "EPT hierarchy".into(),
        data: page,
    };
    let bad = |e: las::Error| Error::las(path, e);
    for v in std::iter::once(hierarchy).chain(extra_evlrs) {
        v.into_raw(true)
            .and_then(|r| r.write_to(&mut out))
            .map_err(bad)?;
    }
    let head = head_bytes(header, &tree, &st, spacing, &laz_vlr, placement, evlrs)?;
    out.seek(SeekFrom::Start(0)).map_err(io)?;
    out.write_all(&head).map_err(io)?;
    let file = out.into_inner().map_err(|e| io(e.into_error()))?;
    drop(file);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn records(points: &[[i32; 3]], rl: usize) -> Vec<u8> {
        let mut v = vec![0u8; points.len() * rl];
        for (r, p) in v.chunks_exact_mut(rl).zip(points) {
            for k in 0..3 {
                r[4 * k..4 * k + 4].copy_from_slice(&p[k].to_le_bytes());
            }
            r[14] = 0x11;
        }
        v
    }

    #[test]
    fn every_point_lies_in_its_node_and_appears_once() {
        let t = las::Vector {
            x: las::Transform {
                scale: 0.01,
                offset: 1000.0,
            },
            y: las::Transform {
                scale: 0.01,
                offset: -50.0,
            },
            z: las::Transform {
                scale: 0.001,
                offset: 0.0,
            },
        };
        // A dense sloped street with a pole: enough for three levels.
        let mut pts = Vec::new();
        let mut s = 7u64;
        for _ in 0..1_000_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = ((s >> 33) % 50_000) as i32;
            let y = ((s >> 13) % 20_000) as i32;
            pts.push([x, y, x / 7 + ((s >> 50) % 300) as i32]);
        }
        for z in 0..30_000 {
            pts.push([2_500, 1_000, z]);
        }
        let rl = 30;
        let recs = records(&pts, rl);
        let tree = Octree::build(&recs, rl, &t);
        let depth = tree.nodes.iter().map(|n| n.key[0]).max().unwrap();
        assert!(depth >= 2, "{} nodes, depth {depth}", tree.nodes.len());
        // Leaves hold at most MAX_NODE_POINTS (the pole's copies of one xy included: it is
        // split in z); interior nodes keep at most one point per cell of their grid.
        let keys: std::collections::HashSet<[i32; 4]> = tree.nodes.iter().map(|n| n.key).collect();
        let tr = [t.x, t.y, t.z];
        for n in &tree.nodes {
            let child = |o: i32| {
                [
                    n.key[0] + 1,
                    2 * n.key[1] + (o & 1),
                    2 * n.key[2] + ((o >> 1) & 1),
                    2 * n.key[3] + (o >> 2),
                ]
            };
            if !(0..8).any(|o| keys.contains(&child(o))) {
                assert!(
                    n.len <= MAX_NODE_POINTS,
                    "leaf {:?}: {} points",
                    n.key,
                    n.len
                );
                continue;
            }
            let (a, b) = tree.node_bounds(n.key);
            let mut cells = std::collections::HashSet::new();
            for &i in tree.points(n) {
                let id: [usize; 3] = std::array::from_fn(|k| {
                    let v = f64::from(pts[i as usize][k]) * tr[k].scale + tr[k].offset;
                    (((v - a[k]) / ((b[k] - a[k]) / GRID as f64)).floor() as usize).min(GRID - 1)
                });
                assert!(cells.insert(id), "{:?}: two points in cell {id:?}", n.key);
            }
        }
        let mut seen = vec![false; pts.len()];
        for node in &tree.nodes {
            let (a, b) = tree.node_bounds(node.key);
            for &i in tree.points(node) {
                let i = i as usize;
                assert!(!seen[i]);
                seen[i] = true;
                for k in 0..3 {
                    let v = f64::from(pts[i][k]) * tr[k].scale + tr[k].offset;
                    assert!(
                        a[k] <= v && v <= b[k],
                        "{:?} {k}: {v} not in {a:?}..{b:?}",
                        node.key
                    );
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        let root = tree.nodes[0];
        assert_eq!(root.key, [0, 0, 0, 0]);
        assert!(root.len > 0);
    }
}
