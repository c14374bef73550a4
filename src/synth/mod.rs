//! Synthetic street scenes: a deterministic generator (`scene`) and a streaming writer that
//! emits the drive as LAS 1.4 point format 7 files with ground truth in extra bytes
//! (`gt_class` u8, `gt_segment` u32) and the per-segment planes in `segments.tsv`.
//!
//! The scene is generated slab by slab (one output file per slab, in parallel), so scenes of
//! 10^8+ points are written with memory bounded by a few slabs.

pub mod buildings;
pub mod drive;
pub mod lidar;
pub mod scene;

pub use scene::{generate_slab, segments, Blocks, SceneParams, SegmentTruth, SynthPoint};

use crate::error::{Error, Result};
use crate::io::laswrite::LasFile;
use crate::io::output::{commit_tmp, tmp_path, write_atomic};
use las::point::Format;
use las::{Builder, Point, Transform, Vector, Version, Vlr};
use rayon::prelude::*;
use std::path::Path;

/// World offset added to the scene's local coordinates, so files look like projected
/// coordinates (RD New around Amsterdam) and exercise large offsets.
pub const WORLD_OFFSET: [f64; 3] = [120_000.0, 485_000.0, 0.0];

/// What `write_scene` produced.
#[derive(Debug, Clone, Copy)]
pub struct SynthStats {
    /// Points written.
    pub points: u64,
    /// Files written.
    pub files: usize,
}

/// The Extra Bytes VLR describing the truth attributes.
pub fn truth_vlr() -> Vlr {
    let mut data = crate::io::extra::descriptor(1, "gt_class", "ground-truth class code");
    data.extend(crate::io::extra::descriptor(
        5,
        "gt_segment",
        "ground-truth segment id",
    ));
    Vlr {
        user_id: "LASF_Spec".into(),
        record_id: 4,
        description: "tessera truth".into(),
        data,
    }
}

fn header() -> Result<las::Header> {
    header_of(7)
}

/// The scenes' header with point format `format` (7 with colour, 6 without).
fn header_of(format: u8) -> Result<las::Header> {
    let mut b = Builder::from((1, 4));
    let mut f = Format::new(format).map_err(|e| Error::Internal(e.to_string()))?;
    f.extra_bytes = 5;
    f.is_compressed = true;
    b.point_format = f;
    b.version = Version::new(1, 4);
    b.transforms = Vector {
        x: Transform {
            scale: 0.001,
            offset: WORLD_OFFSET[0],
        },
        y: Transform {
            scale: 0.001,
            offset: WORLD_OFFSET[1],
        },
        z: Transform {
            scale: 0.001,
            offset: WORLD_OFFSET[2],
        },
    };
    b.generating_software = format!("tessera synth {}", env!("CARGO_PKG_VERSION"));
    b.vlrs.push(truth_vlr());
    b.into_header().map_err(|e| Error::Internal(e.to_string()))
}

fn to_point(p: &SynthPoint) -> Point {
    let mut extra = vec![p.class];
    extra.extend_from_slice(&p.segment.to_le_bytes());
    Point {
        x: p.x + WORLD_OFFSET[0],
        y: p.y + WORLD_OFFSET[1],
        z: p.z + WORLD_OFFSET[2],
        intensity: p.intensity,
        return_number: 1,
        number_of_returns: 1,
        classification: las::point::Classification::Unclassified,
        gps_time: Some(p.gps_time),
        color: Some(las::Color::new(p.rgb[0], p.rgb[1], p.rgb[2])),
        point_source_id: 1,
        extra_bytes: extra,
        ..Default::default()
    }
}

/// Writes the scene as `scene_NNNNN.laz` files of `file_length_m` metres of drive each, plus
/// `segments.tsv`. Existing files of the same names are replaced atomically.
pub fn write_scene(params: &SceneParams, dir: &Path, file_length_m: f64) -> Result<SynthStats> {
    if !(params.length_m > 0.0 && params.length_m.is_finite()) {
        return Err(Error::Config(format!(
            "synth: length_m must be positive, got {}",
            params.length_m
        )));
    }
    if !params.blocks.is_valid() {
        return Err(Error::Config(format!(
            "synth: building blocks need 1 <= min_building_m <= max_building_m and min_building_m <= block_m (finite), got {:?}",
            params.blocks
        )));
    }
    // Slab bounds on whole metres keep the scene independent of the file length.
    let step = file_length_m.round().max(1.0);
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let n = (params.length_m / step).ceil() as usize;
    let header = header()?;
    let counts: Vec<u64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let x0 = i as f64 * step;
            let x1 = ((i + 1) as f64 * step).min(params.length_m.ceil());
            let mut pts = Vec::new();
            generate_slab(params, x0, x1, &mut pts);
            write_points(&dir.join(format!("scene_{i:05}.laz")), &header, &pts)?;
            Ok(pts.len() as u64)
        })
        .collect::<Result<_>>()?;
    write_segments_tsv(dir, &segments(params))?;
    Ok(SynthStats {
        points: counts.iter().sum(),
        files: n,
    })
}

/// Writes `pts` to `path` (LAZ, atomically: temp file, then rename).
fn write_points(path: &Path, header: &las::Header, pts: &[SynthPoint]) -> Result<()> {
    write_points_with(path, header, pts, |q| q)
}

/// [`write_points`], each point passed through `adapt` (e.g. to drop colour).
fn write_points_with(
    path: &Path,
    header: &las::Header,
    pts: &[SynthPoint],
    adapt: impl Fn(Point) -> Point,
) -> Result<()> {
    let tmp = tmp_path(path);
    let res = (|| -> Result<()> {
        let mut w = LasFile::create(&tmp, header.clone(), Default::default())?;
        for p in pts {
            w.write_point(adapt(to_point(p)))?;
        }
        w.finish()
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    commit_tmp(&tmp, path)
}

/// Writes every `every`-th revolution of the simulated drive `p` as its own file
/// `scan_NNNNN.laz` (NNNNN: the revolution): one scan in the world frame, as a spinning LiDAR
/// without a camera records it (format 6, no colour), with the truth attributes, plus
/// `segments.tsv`. Single scans keep the scanner's ring pattern, range fall-off and shadows,
/// which an accumulated drive fills in.
pub fn write_scans(p: &lidar::LidarParams, dir: &Path, every: u64) -> Result<SynthStats> {
    p.validate()
        .map_err(|e| Error::Config(format!("synth --mcap: {e}")))?;
    if every == 0 {
        return Err(Error::Config(
            "synth: --scans-every must be at least 1".into(),
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let header = header_of(6)?;
    let revs: Vec<u64> = (0..p.revolutions()).step_by(every as usize).collect();
    let counts: Vec<u64> = revs
        .par_iter()
        .map(|&k| {
            let rev = lidar::simulate_revolution(p, k);
            let t = drive::DRIVE_T0_S as f64 + rev.start_ns as f64 * 1e-9;
            let pts: Vec<SynthPoint> = rev
                .beams
                .iter()
                .flatten()
                .map(|r| SynthPoint {
                    x: r.world[0],
                    y: r.world[1],
                    z: r.world[2],
                    rgb: [0; 3],
                    intensity: r.intensity.clamp(0.0, 65535.0) as u16,
                    gps_time: t,
                    class: r.class,
                    segment: r.segment,
                })
                .collect();
            write_points_with(
                &dir.join(format!("scan_{k:05}.laz")),
                &header,
                &pts,
                |mut q| {
                    q.color = None;
                    q
                },
            )?;
            Ok(pts.len() as u64)
        })
        .collect::<Result<_>>()?;
    write_segments_tsv(dir, &segments(&p.scene))?;
    Ok(SynthStats {
        points: counts.iter().sum(),
        files: revs.len(),
    })
}

/// Writes the reference segments as `segments.tsv` (world coordinates).
fn write_segments_tsv(dir: &Path, segs: &[SegmentTruth]) -> Result<()> {
    let mut tsv = String::from("id\tclass\tkind\tplanar\tnx\tny\tnz\td\tx_min\tx_max\n");
    for s in segs {
        // Plane n·p + d = 0 in local coordinates → world: d' = d − n·offset.
        let d = s.d
            - (s.normal[0] * WORLD_OFFSET[0]
                + s.normal[1] * WORLD_OFFSET[1]
                + s.normal[2] * WORLD_OFFSET[2]);
        tsv.push_str(&format!(
            "{}\t{}\t{}\t{}\t{:.9}\t{:.9}\t{:.9}\t{:.6}\t{:.3}\t{:.3}\n",
            s.id,
            s.class,
            s.kind,
            s.planar as u8,
            s.normal[0],
            s.normal[1],
            s.normal[2],
            d,
            s.x_min + WORLD_OFFSET[0],
            s.x_max + WORLD_OFFSET[0]
        ));
    }
    write_atomic(&dir.join("segments.tsv"), tsv.as_bytes())
}

/// Writes the building scene (see [`buildings`]) as `buildings.laz` plus `segments.tsv`.
pub fn write_buildings(params: &buildings::BuildingParams, dir: &Path) -> Result<SynthStats> {
    if !(params.points_per_m2 > 0.0 && params.points_per_m2.is_finite()) || params.houses == 0 {
        return Err(Error::Config(format!(
            "synth buildings: need houses >= 1 and a positive density, got {} houses at {} points/m²",
            params.houses, params.points_per_m2
        )));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let (pts, segs) = buildings::generate(params);
    write_points(&dir.join("buildings.laz"), &header()?, &pts)?;
    write_segments_tsv(dir, &segs)?;
    Ok(SynthStats {
        points: pts.len() as u64,
        files: 1,
    })
}
