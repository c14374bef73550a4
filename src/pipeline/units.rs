//! The inputs' linear unit, and the configuration in that unit.
//!
//! tessera's distance parameters are metres. An input in feet (a US State Plane CRS, say) is
//! processed in its own unit, bit-exact, with the parameters converted to that unit — not
//! with its coordinates converted — so outputs keep the input's coordinates, scales and CRS.
//! Horizontal and vertical units must agree: the ground filter's angles and the segmenter's
//! normals mix x, y and z.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::crs::{CrsInfo, LinearUnit, UnitsReport};
use std::path::{Path, PathBuf};

fn is_las(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("las") || e.eq_ignore_ascii_case("laz"))
}

/// The unit of one input: horizontal and vertical must agree, and coordinates must be
/// projected. `Ok(None)`: the file has no CRS, or states no unit.
fn unit_of(path: &Path, info: &CrsInfo) -> Result<Option<LinearUnit>> {
    if info.geographic {
        return Err(Error::bad_input(
            path,
            "coordinates are longitude/latitude (a geographic CRS): tessera's parameters are distances; reproject the input to a projected CRS (or set crs.units if its CRS record is wrong)",
        ));
    }
    match (&info.horizontal, &info.vertical) {
        (Some(h), Some(v)) if !h.same_as(v) => Err(Error::bad_input(
            path,
            format!(
                "x and y are in {} but z is in {} ({}): angles and normals need one unit; convert z first (or set crs.units if the CRS records are wrong)",
                h.name, v.name, info.source
            ),
        )),
        (Some(h), _) => Ok(Some(h.clone())),
        (None, v) => Ok(v.clone()),
    }
}

/// Resolves the unit of the LAS/LAZ files among `inputs` (MCAP drives and PCD files are
/// metres) and returns the configuration in that unit. Unreadable files are left to the
/// run's scan, which reports them (or skips them with `pipeline.keep_going`).
pub fn for_inputs(cfg: &Config, inputs: &[PathBuf]) -> Result<(Config, UnitsReport)> {
    let stated = cfg.crs.stated_unit()?;
    let (unit, source) = match stated {
        Some(u) => (u, "crs.units".to_string()),
        None => {
            let mut found: Option<(LinearUnit, PathBuf, String)> = None;
            for p in inputs.iter().filter(|p| is_las(p)) {
                let Ok(f) = crate::io::input::scan_file(p, 0) else {
                    continue;
                };
                let info = CrsInfo::of_header(&f.header).map_err(|e| {
                    Error::bad_input(
                        p,
                        format!("CRS: {e}; set crs.units to state the coordinates' unit"),
                    )
                })?;
                let Some(u) = unit_of(p, &info)? else {
                    continue;
                };
                match &found {
                    Some((first, fp, _)) if !first.same_as(&u) => {
                        return Err(Error::Config(format!(
                            "inputs in different units: {} is in {} and {} in {}; run them separately or convert one",
                            fp.display(),
                            first.name,
                            p.display(),
                            u.name
                        )))
                    }
                    Some(_) => {}
                    None => found = Some((u, p.clone(), info.source.clone())),
                }
            }
            match found {
                Some((u, p, src)) => (u, format!("{src} of {}", p.display())),
                None => (
                    LinearUnit::metre(),
                    "no input states a unit: metres assumed".to_string(),
                ),
            }
        }
    };
    if unit.is_metre() {
        return Ok((
            cfg.clone(),
            UnitsReport {
                unit,
                source,
                converted: Vec::new(),
            },
        ));
    }
    let (converted_cfg, converted) = cfg.in_length_unit(unit.metres)?;
    tracing::info!(
        "inputs in {} ({source}): {} distance parameters converted from metres",
        unit.name,
        converted.len()
    );
    Ok((
        converted_cfg,
        UnitsReport {
            unit,
            source,
            converted,
        },
    ))
}
