//! The stitcher on a synthetic row of tiles fed in pipeline-like orders: ids, determinism,
//! closing, and bounded state.

use super::*;
use crate::model::{Rect, TileId};

const TILE_M: f64 = 10.0;
const STRIP_M: f64 = 2.0;

/// Point index `j` sits at x = 0.1 j + 0.05 (y = 5); its pid and ordinal are `j`.
fn x_of(j: u64) -> f64 {
    0.1 * j as f64 + 0.05
}

/// Tile `i` of a row: label 1 = a "road" crossing every border except before tiles whose
/// index is a multiple of `break_every` (there the road changes: the neighbours' pieces share
/// no points), label 2 = an interior segment (no border points), label 3 = a piece only this
/// tile sees in its east buffer (the east tile leaves those points unlabelled).
fn summary(i: i64, break_every: i64) -> BorderSummary {
    let core = Rect {
        x0: TILE_M * i as f64,
        y0: 0.0,
        x1: TILE_M * (i + 1) as f64,
        y1: 10.0,
    };
    let first = (100 * i) as u64;
    let rec = |j: u64, label: u32| BorderRecord {
        pid: j,
        label,
        dx: (x_of(j) - core.x0) as f32,
        dy: 5.0,
    };
    let mut inner = Vec::new();
    let mut outer = Vec::new();
    // Road points within the strip on both sides of both borders. A break at a border: the
    // tile west of it labels its east buffer 0 instead of 1.
    let broken_east = (i + 1) % break_every == 0;
    let broken_west = i % break_every == 0;
    for j in first.saturating_sub(20)..first + 120 {
        let x = x_of(j);
        if x < core.x0 - STRIP_M || x >= core.x1 + STRIP_M || (x < 0.0) {
            continue;
        }
        let is_core = core.contains(x, 5.0);
        if is_core && x >= core.x0 + STRIP_M && x < core.x1 - STRIP_M {
            continue;
        }
        if !is_core && ((x < core.x0 && broken_west) || (x >= core.x1 && broken_east)) {
            continue;
        }
        if is_core {
            inner.push(rec(j, 1));
        } else {
            outer.push(rec(j, 1));
        }
    }
    // The stray buffer piece: a second row of points at y = 7 east of the core.
    for j in 0..8u64 {
        outer.push(BorderRecord {
            pid: 1_000_000 + 100 * i as u64 + j,
            label: 3,
            dx: (TILE_M + 0.5) as f32,
            dy: 7.0 + 0.01 * j as f32,
        });
    }
    BorderSummary {
        tile: TileId::grid(i, 0),
        name: format!("t{i}"),
        core,
        anchors: vec![first, first + 50, u64::MAX],
        inner,
        outer,
    }
}

/// Feeds `n` tiles: cell `i` is released at step `i` (with the next cell still open), its
/// tile arrives `lag(i)` steps later, then its completion. Returns ids per tile, the stats and
/// the most cell entries held.
fn feed(
    n: i64,
    break_every: i64,
    lag: impl Fn(i64) -> i64,
) -> (Vec<(i64, Vec<u64>)>, StitchStats, usize) {
    feed_spilling(n, break_every, lag, None)
}

/// [`feed`] with the frontier capped at `spill.1` bytes in memory, spilling into `spill.0`.
fn feed_spilling(
    n: i64,
    break_every: i64,
    lag: impl Fn(i64) -> i64,
    spill: Option<(&std::path::Path, u64)>,
) -> (Vec<(i64, Vec<u64>)>, StitchStats, usize) {
    let mut st: Stitcher<i64> = Stitcher::new(StitchParams::default(), STRIP_M);
    if let Some((dir, cap)) = spill {
        st = st.spill_beyond(dir, cap);
    }
    let mut arrivals: Vec<(i64, i64)> = (0..n).map(|i| (i + lag(i), i)).collect();
    arrivals.sort();
    let mut next = 0;
    let mut out = Vec::new();
    let mut max_cells = 0;
    for step in 0..=n + 10 {
        if step < n {
            let mut batch = vec![CellRelease {
                cell: (step, 0),
                has_core: true,
                open_neighbours: vec![(step + 1, 0)],
            }];
            if step == 0 {
                // West of the row: opened by buffer points only, released empty with cell 0.
                batch.insert(
                    0,
                    CellRelease {
                        cell: (-1, 0),
                        has_core: false,
                        open_neighbours: vec![(0, 0)],
                    },
                );
            }
            st.released(&batch);
        }
        if step == n {
            st.released(&[CellRelease {
                cell: (n, 0),
                has_core: false,
                open_neighbours: vec![],
            }]);
        }
        while next < arrivals.len() && arrivals[next].0 <= step {
            let i = arrivals[next].1;
            st.add_tile(summary(i, break_every), i).unwrap();
            st.cell_done((i, 0), 1).unwrap();
            next += 1;
        }
        max_cells = max_cells.max(st.cells_held());
        out.extend(st.take_ready().into_iter().map(|r| (r.payload, r.ids)));
    }
    st.finish().unwrap();
    out.extend(st.take_ready().into_iter().map(|r| (r.payload, r.ids)));
    out.sort();
    (out, st.stats().clone(), max_cells)
}

#[test]
fn ids_follow_components_and_not_the_arrival_order() {
    let (a, sa, _) = feed(30, 7, |_| 0);
    let (b, _, _) = feed(30, 7, |i| (i * 7919) % 4);
    let (c, _, _) = feed(30, 7, |i| 30 - i);
    assert_eq!(a.len(), 30);
    assert_eq!(a, b);
    assert_eq!(a, c);
    for (i, ids) in &a {
        // The road: one id per stretch between breaks, 1 + the smallest ordinal of its
        // first tile's points.
        let start = i - i % 7;
        assert_eq!(ids[0], 100 * start as u64 + 1, "tile {i}");
        assert_eq!(ids[1], 100 * *i as u64 + 51, "tile {i}");
        assert_eq!(ids[2], 0, "buffer-only piece has no id");
    }
    assert_eq!(sa.segments_crossing_borders, 5); // stretches 0-6, 7-13, 14-20, 21-27, 28-29
    assert_eq!(sa.max_tiles_per_segment, 7);
    assert_eq!(sa.global_segments, 30 + 5);
    // The stray piece shares no labelled point with the east tile: never a candidate.
    assert_eq!(sa.rejected_pairs, 0);
}

#[test]
fn frontier_stays_flat_as_the_row_grows() {
    let (_, s50, c50) = feed(50, 5, |i| i % 3);
    let (_, s200, c200) = feed(200, 5, |i| i % 3);
    assert_eq!(s50.frontier_tiles_max, s200.frontier_tiles_max);
    assert_eq!(s50.frontier_records_max, s200.frontier_records_max);
    assert_eq!(s50.waiting_tiles_max, s200.waiting_tiles_max);
    assert_eq!(s50.open_nodes_max, s200.open_nodes_max);
    assert_eq!(c50, c200);
    assert!(s200.frontier_tiles_max <= 6, "{s200:?}");
    assert!(c200 <= 10, "{c200}");
}

#[test]
fn a_run_long_segment_keeps_its_tiles_waiting_but_not_their_summaries() {
    let (out, s, _) = feed(60, 1000, |_| 0);
    assert!(out.iter().all(|(_, ids)| ids[0] == 1));
    // Every tile but the last (whose closing finalises the road) waits for the road to become
    // final at the end of the run, but only the summaries of a few tiles are held at a time.
    assert_eq!(s.waiting_tiles_max, 59);
    assert!(s.frontier_tiles_max <= 3, "{s:?}");
    assert_eq!(s.segments_crossing_borders, 1);
    assert_eq!(s.max_tiles_per_segment, 60);
}

/// A frontier capped below one summary keeps every summary in the spill file, reads them
/// back to match arriving neighbours, and stitches exactly as in memory; the file is gone
/// with the stitcher.
#[test]
fn a_spilled_frontier_stitches_the_same() {
    let dir = tempfile::tempdir().unwrap();
    for lag in [|_: i64| 0, |i: i64| (i * 7919) % 4, |i: i64| 30 - i] {
        let (a, sa, _) = feed(30, 7, lag);
        let (b, sb, _) = feed_spilling(30, 7, lag, Some((dir.path(), 0)));
        assert_eq!(a, b);
        assert_eq!(
            (
                sa.merges,
                sa.accepted_pairs,
                sa.shared_points,
                sa.global_segments
            ),
            (
                sb.merges,
                sb.accepted_pairs,
                sb.shared_points,
                sb.global_segments
            )
        );
        assert_eq!(sb.spilled_summaries, 30);
        assert!(sb.spill_reads > 0 && sb.spill_bytes_max > 0, "{sb:?}");
        let one = summary(1, 7).bytes() as u64;
        assert!(
            sb.frontier_bytes_max <= one,
            "{} > {one}",
            sb.frontier_bytes_max
        );
        // A cap of two summaries keeps the newest in memory (fewer reads), and room is made
        // before a summary is added: never more than the cap in memory.
        let cap = 2 * one + one / 2;
        let (c, sc, _) = feed_spilling(30, 7, lag, Some((dir.path(), cap)));
        assert_eq!(a, c);
        assert!(sc.spill_reads < sb.spill_reads, "{sc:?}");
        assert!(
            sc.frontier_bytes_max <= cap,
            "{} > {cap}",
            sc.frontier_bytes_max
        );
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn broken_message_flows_are_errors() {
    let mut st: Stitcher<()> = Stitcher::new(StitchParams::default(), STRIP_M);
    // A tile for a cell never released.
    assert!(matches!(
        st.add_tile(summary(0, 5), ()),
        Err(StitchError::UnknownCell { .. })
    ));
    st.released(&[CellRelease {
        cell: (0, 0),
        has_core: true,
        open_neighbours: vec![(1, 0)],
    }]);
    // Completion announcing more tiles than arrived.
    assert!(st.cell_done((0, 0), 1).is_err());
    st.add_tile(summary(0, 5), ()).unwrap();
    st.cell_done((0, 0), 1).unwrap();
    // Cell 1 was open when cell 0 was released but never released: the run cannot finish.
    assert!(matches!(
        st.finish(),
        Err(StitchError::Incomplete(1, (1, 0)))
    ));
    // A summary with a label beyond the tile's segments.
    let mut bad = summary(3, 5);
    bad.outer[0].label = 9;
    assert!(matches!(
        bad.validate(),
        Err(StitchError::BadSummary { .. })
    ));
}
