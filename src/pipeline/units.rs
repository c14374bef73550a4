//! The inputs' linear unit, and the configuration in that unit.
//!
//! tessera's distance parameters are metres. An input in feet (a US State Plane CRS, say) is
//! processed in its own unit, bit-exact, with the parameters converted to that unit — not
//! with its coordinates converted — so outputs keep the input's coordinates, scales and CRS.
//! Heights in another unit than x and y are scaled into the unit of x and y for the stages
//! only: the ground filter's angles and the segmenter's normals mix x, y and z.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::crs::{CrsInfo, LinearUnit, UnitsReport};
use std::path::{Path, PathBuf};

fn is_las(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("las") || e.eq_ignore_ascii_case("laz"))
}

/// Relative difference under which two units are taken as one: the international and the
/// US survey foot differ by 2 ppm (0.2 mm over 100 m), far below any parameter's precision,
/// and files mix the two in their horizontal and vertical CRSs.
const SAME_UNIT: f64 = 1e-5;

fn near(a: &LinearUnit, b: &LinearUnit) -> bool {
    (a.metres / b.metres - 1.0).abs() < SAME_UNIT
}

/// What one input's CRS records say its coordinates are in.
#[derive(Debug, Clone, PartialEq)]
struct InputUnits {
    /// Unit of x and y.
    horizontal: LinearUnit,
    /// Unit of z, when the records say it differs from that of x and y.
    vertical: Option<LinearUnit>,
}

/// A CRS as a user would recognise it in a message: kind, name and EPSG code.
fn describe(kind: &str, info: &CrsInfo) -> String {
    let mut s = format!("a {kind} CRS");
    if let Some(n) = &info.name {
        s.push_str(&format!(" \"{n}\""));
    }
    if let Some(c) = info.epsg {
        s.push_str(&format!(" (EPSG:{c})"));
    }
    format!("{s}, from its {}", info.source)
}

/// The UTM zone around a longitude/latitude box, as an EPSG code (WGS 84 / UTM).
fn utm_epsg(b: &las::Bounds) -> (u32, u32, char) {
    let lon = 0.5 * (b.min.x + b.max.x);
    let lat = 0.5 * (b.min.y + b.max.y);
    let zone = (((lon + 180.0) / 6.0).floor() as i64).clamp(0, 59) as u32 + 1;
    if lat >= 0.0 {
        (32600 + zone, zone, 'N')
    } else {
        (32700 + zone, zone, 'S')
    }
}

/// The units of one input with `points` points within `bounds`. Geographic coordinates
/// (degrees) and Earth-centred ones are refused, with what to do; a record that contradicts
/// the coordinates (a geographic or geocentric CRS over coordinates that cannot be either)
/// is wrong but harmless: a warning, and the coordinates are taken as projected.
/// `Ok(None)`: the file has no CRS, or states no unit.
fn unit_of(path: &Path, info: &CrsInfo, bounds: &las::Bounds) -> Result<Option<InputUnits>> {
    let (lo, hi) = (bounds.min, bounds.max);
    if info.geographic {
        let degrees = lo.x >= -360.0 && hi.x <= 360.0 && lo.y >= -90.0 && hi.y <= 90.0;
        if degrees {
            let (epsg, zone, hemi) = utm_epsg(bounds);
            return Err(Error::bad_input(
                path,
                format!(
                    "coordinates are longitude/latitude in degrees ({}); tessera's parameters are distances, and a degree east is not a degree north: reproject to a projected CRS first, e.g. UTM zone {zone}{hemi}: `pdal translate {} OUT.laz reprojection --filters.reprojection.out_srs=EPSG:{epsg}` (or set crs.units if the CRS record is wrong)",
                    describe("geographic", info),
                    path.display()
                ),
            ));
        }
        tracing::warn!(
            "{}: the CRS record names {}, but the coordinates (x {:.0} .. {:.0}, y {:.0} .. {:.0}) are no longitudes/latitudes: the record is wrong; taken as metres (set crs.units to state the unit)",
            path.display(),
            describe("geographic", info),
            lo.x,
            hi.x,
            lo.y,
            hi.y
        );
        return Ok(None);
    }
    if info.geocentric {
        let m = info.horizontal.as_ref().map_or(1.0, |u| u.metres);
        let r = |x: f64, y: f64, z: f64| m * (x * x + y * y + z * z).sqrt();
        let (r0, r1) = (r(lo.x, lo.y, lo.z), r(hi.x, hi.y, hi.z));
        // Earth-centred coordinates lie about 6,357-6,378 km from the origin.
        if (6.0e6..6.7e6).contains(&r0) && (6.0e6..6.7e6).contains(&r1) {
            return Err(Error::bad_input(
                path,
                format!(
                    "coordinates are Earth-centred x/y/z ({}): z is not up, so ground and heights have no meaning; reproject to a projected CRS with heights first (or set crs.units if the CRS record is wrong)",
                    describe("geocentric", info)
                ),
            ));
        }
        tracing::warn!(
            "{}: the CRS record names {}, but the coordinates are not Earth-centred (they lie {:.0} km from the Earth's centre): the record is wrong; taken as projected coordinates in {}",
            path.display(),
            describe("geocentric", info),
            r0.max(r1) / 1000.0,
            info.horizontal.as_ref().map_or("metres", |u| &u.name)
        );
    }
    Ok(match (&info.horizontal, &info.vertical) {
        (Some(h), Some(v)) if !near(h, v) => Some(InputUnits {
            horizontal: h.clone(),
            vertical: Some(v.clone()),
        }),
        (Some(h), _) => Some(InputUnits {
            horizontal: h.clone(),
            vertical: None,
        }),
        // Only a vertical unit: the horizontal one is unknown, so the same is assumed.
        (None, Some(v)) => Some(InputUnits {
            horizontal: v.clone(),
            vertical: None,
        }),
        (None, None) => None,
    })
}

/// Resolves the unit of the LAS/LAZ files among `inputs` (MCAP drives and PCD files are
/// metres) and returns the configuration in that unit. Unreadable files are left to the
/// run's scan, which reports them (or skips them with `pipeline.keep_going`); files without
/// points have no coordinates to be wrong about and are not asked.
///
/// Heights in another unit than x and y (NAVD88 heights in US survey feet over a metre
/// projection, as PDAL's Autzen files are) are not refused: the stages see z in the unit of
/// x and y ([`crate::model::RecordLayout::z_to_xy`], in [`UnitsReport::z_to_xy`]), so every
/// distance, angle and normal is in one unit, while the records, and so the outputs, keep
/// the input's heights bit for bit.
pub fn for_inputs(cfg: &Config, inputs: &[PathBuf]) -> Result<(Config, UnitsReport)> {
    let stated = cfg.crs.stated_unit()?;
    let mut found: Option<(InputUnits, PathBuf, String)> = None;
    for p in inputs.iter().filter(|p| is_las(p)) {
        let Ok(f) = crate::io::input::scan_file(p, 0) else {
            continue;
        };
        if f.points == 0 {
            continue;
        }
        let info = CrsInfo::of_header(&f.header);
        for note in &info.notes {
            tracing::warn!(
                "{}: {note}; {}",
                p.display(),
                if stated.is_some() {
                    "crs.units states the unit"
                } else {
                    "its unit is read from the other CRS records, else metres are assumed (set crs.units to state it)"
                }
            );
        }
        if stated.is_some() {
            continue;
        }
        let Some(u) = unit_of(p, &info, &f.header.bounds())? else {
            continue;
        };
        match &found {
            Some((first, fp, _)) if !near(&first.horizontal, &u.horizontal) => {
                return Err(Error::Config(format!(
                    "inputs in different units: {} is in {} and {} in {}; run them separately or convert one",
                    fp.display(),
                    first.horizontal.name,
                    p.display(),
                    u.horizontal.name
                )))
            }
            Some((first, fp, _)) if first.vertical != u.vertical => {
                let name = |i: &InputUnits| i.vertical.as_ref().unwrap_or(&i.horizontal).name.clone();
                return Err(Error::Config(format!(
                    "inputs with heights in different units: {} has heights in {} and {} in {}; run them separately or convert one",
                    fp.display(),
                    name(first),
                    p.display(),
                    name(&u)
                )));
            }
            Some(_) => {}
            None => found = Some((u, p.clone(), info.source.clone())),
        }
    }
    let (unit, vertical, source) = match (stated, found) {
        (Some(u), _) => (u, None, "crs.units".to_string()),
        (None, Some((u, p, src))) => (
            u.horizontal,
            u.vertical,
            format!("{src} of {}", p.display()),
        ),
        (None, None) => (
            LinearUnit::metre(),
            None,
            "no input states a unit: metres assumed".to_string(),
        ),
    };
    let z_to_xy = vertical.as_ref().map_or(1.0, |v| v.metres / unit.metres);
    if let Some(v) = &vertical {
        tracing::info!(
            "heights in {} and x/y in {} ({source}): the stages see heights in {} (× {z_to_xy:.9}); outputs keep the input's heights",
            v.name,
            unit.name,
            unit.name
        );
    }
    let (converted_cfg, converted) = if unit.is_metre() {
        (cfg.clone(), Vec::new())
    } else {
        let (c, converted) = cfg.in_length_unit(unit.metres)?;
        tracing::info!(
            "inputs in {} ({source}): {} distance parameters converted from metres",
            unit.name,
            converted.len()
        );
        (c, converted)
    };
    Ok((
        converted_cfg,
        UnitsReport {
            unit,
            vertical_unit: vertical,
            z_to_xy,
            source,
            converted,
        },
    ))
}
