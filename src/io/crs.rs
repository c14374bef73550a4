//! The coordinate reference system of LAS/LAZ inputs, as far as tessera needs it:
//!
//! - the **linear unit** of the coordinates: every distance parameter of tessera is in metres,
//!   so an input in feet gets its parameters converted (see [`crate::config::Config::in_length_unit`]);
//! - an **OGC WKT** for outputs in point formats 6–10, which LAS 1.4 R15 requires to carry
//!   their CRS as WKT, not as GeoTIFF keys (converted from the EPSG code of the keys).
//!
//! Read from the OGC WKT record (2112) when there is one, else from the GeoTIFF keys (34735,
//! 34736): `ProjLinearUnitsGeoKey` (3076), or the unit of the EPSG code in
//! `ProjectedCSTypeGeoKey` (3072); the vertical unit from the vertical CRS (`VerticalUnitsGeoKey`
//! 4099, or the WKT's vertical part), else taken equal to the horizontal one.

use las::crs::GeoTiffData;

/// A linear unit: its name and length in metres.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LinearUnit {
    /// Name, e.g. "metre", "US survey foot".
    pub name: String,
    /// Metres per unit.
    pub metres: f64,
}

impl LinearUnit {
    /// The metre.
    pub fn metre() -> LinearUnit {
        LinearUnit {
            name: "metre".into(),
            metres: 1.0,
        }
    }

    /// The international foot (0.3048 m, EPSG 9002).
    pub fn foot() -> LinearUnit {
        LinearUnit {
            name: "foot".into(),
            metres: 0.3048,
        }
    }

    /// The US survey foot (1200/3937 m, EPSG 9003).
    pub fn us_survey_foot() -> LinearUnit {
        LinearUnit {
            name: "US survey foot".into(),
            metres: 1200.0 / 3937.0,
        }
    }

    /// The unit of EPSG unit-of-measure code `code`, for the codes LAS files use.
    pub fn from_epsg(code: u16) -> Option<LinearUnit> {
        let (name, metres) = match code {
            9001 => ("metre", 1.0),
            9002 => ("foot", 0.3048),
            9003 => ("US survey foot", 1200.0 / 3937.0),
            9005 => ("Clarke's foot", 0.3047972654),
            9036 => ("kilometre", 1000.0),
            9070 => ("British foot (1865)", 0.30480083333333),
            9095 => ("British foot (1936)", 0.3048007491),
            _ => return None,
        };
        Some(LinearUnit {
            name: name.into(),
            metres,
        })
    }

    /// True for the metre (to a part in 10^9).
    pub fn is_metre(&self) -> bool {
        (self.metres - 1.0).abs() < 1e-9
    }

    /// True when `self` and `other` are the same length (to a part in 10^9).
    pub fn same_as(&self, other: &LinearUnit) -> bool {
        (self.metres / other.metres - 1.0).abs() < 1e-9
    }
}

/// What the run found and did (`summary.json` "units").
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct UnitsReport {
    /// The inputs' linear unit.
    pub unit: LinearUnit,
    /// The heights' unit when it differs from that of x and y (PDAL's Autzen files: x/y in
    /// metres, NAVD88 heights in US survey feet); `None` when they agree.
    pub vertical_unit: Option<LinearUnit>,
    /// Heights are multiplied by this for the stages, so that they see z in the unit of x
    /// and y (1 when the units agree); the records keep the input's heights.
    pub z_to_xy: f64,
    /// Where it came from: the CRS records of the inputs, `crs.units`, or the metre assumed
    /// for inputs without a CRS.
    pub source: String,
    /// Parameters converted from metres to `unit` (none for metre inputs).
    pub converted: Vec<String>,
}

/// What the header says about the CRS.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CrsInfo {
    /// Unit of x and y; `None` when the header has no CRS or does not say.
    pub horizontal: Option<LinearUnit>,
    /// Unit of z, when the header says (else take the horizontal one).
    pub vertical: Option<LinearUnit>,
    /// The coordinates are longitude/latitude (degrees), not projected.
    pub geographic: bool,
    /// The CRS is geocentric (Earth-centred x, y, z in metres: z is not "up").
    pub geocentric: bool,
    /// The CRS's name, when the record gives one (for messages).
    pub name: Option<String>,
    /// EPSG code of the horizontal CRS, when known.
    pub epsg: Option<u16>,
    /// The header's OGC WKT record, when it has one.
    pub wkt: Option<String>,
    /// Where the unit was read, for the run report.
    pub source: String,
    /// What was odd but harmless in the records (each a sentence for a warning): a record
    /// tessera could not use, a key that contradicts the others. The unit is then read from
    /// the records that remain, else left unknown.
    pub notes: Vec<String>,
}

impl CrsInfo {
    /// Reads the CRS records of `header`. Records that cannot be read or contradict
    /// themselves do not make the file unreadable (laspy and PDAL read such files): they are
    /// left out, with a note ([`CrsInfo::notes`]), and the unit comes from what remains.
    pub fn of_header(header: &las::Header) -> CrsInfo {
        let mut notes = Vec::new();
        if let Some(bytes) = header.get_wkt_crs_bytes() {
            let text = String::from_utf8_lossy(bytes);
            let text = text.trim_end_matches('\0').trim();
            // Some writers leave an empty WKT as `""`: no CRS, said with two characters.
            let empty = text.is_empty() || text.chars().all(|c| c == '"' || c.is_whitespace());
            if empty {
                notes.push("its OGC WKT record is empty".to_string());
            } else {
                match from_wkt(text) {
                    Ok(mut info) => {
                        info.wkt = Some(text.to_string());
                        info.source = "OGC WKT record".into();
                        return info;
                    }
                    Err(e) => notes.push(format!("its OGC WKT record cannot be read ({e})")),
                }
            }
        }
        let mut info = match header.get_geotiff_crs() {
            Ok(Some(keys)) => from_geotiff(&keys, &mut notes),
            Ok(None) => CrsInfo::default(),
            Err(e) => {
                notes.push(format!("its GeoTIFF key records cannot be read ({e})"));
                CrsInfo::default()
            }
        };
        info.notes = notes;
        info
    }

    /// An OGC WKT for a LAS 1.4 output of this CRS: the header's own, else the EPSG code's.
    pub fn output_wkt(&self) -> Option<String> {
        self.wkt.clone().or_else(|| {
            self.epsg
                .and_then(crs_definitions::from_code)
                .map(|d| d.wkt.to_string())
        })
    }
}

/// Units and EPSG code from GeoTIFF keys. A unit key holding a code that is no length unit
/// (LAS 1.3 waveform samples put the projection's code, 32632, in ProjLinearUnitsGeoKey) is
/// left out with a note, and the unit is read from the projected CRS's code instead.
fn from_geotiff(keys: &las::crs::GeoTiffCrs, notes: &mut Vec<String>) -> CrsInfo {
    let u16_key = |id: u16| {
        keys.entries
            .iter()
            .find(|e| e.id == id)
            .and_then(|e| match e.data {
                GeoTiffData::U16(v) => Some(v),
                _ => None,
            })
    };
    let double_key = |id: u16| {
        keys.entries
            .iter()
            .find(|e| e.id == id)
            .and_then(|e| match &e.data {
                GeoTiffData::Doubles(v) => v.first().copied(),
                _ => None,
            })
    };
    let mut info = CrsInfo {
        source: "GeoTIFF keys".into(),
        ..CrsInfo::default()
    };
    // GTModelTypeGeoKey: 1 projected, 2 geographic, 3 geocentric.
    let model = u16_key(1024);
    info.geographic = model == Some(2);
    info.geocentric = model == Some(3);
    let projected = u16_key(3072).filter(|c| (1024..32767).contains(c));
    let geographic = u16_key(2048).filter(|c| (1024..32767).contains(c));
    info.epsg = if info.geographic {
        geographic
    } else {
        projected
    };
    if !info.geographic {
        info.horizontal = match u16_key(3076) {
            Some(32767) => double_key(3077).filter(|m| *m > 0.0).map(|m| LinearUnit {
                name: format!("user-defined unit of {m} m"),
                metres: m,
            }),
            Some(code) => unit_key(code, "ProjLinearUnitsGeoKey", notes),
            None => None,
        };
        if info.horizontal.is_some() {
            info.source = "GeoTIFF ProjLinearUnitsGeoKey".into();
        } else if let Some(code) = projected {
            if let Some(def) = crs_definitions::from_code(code) {
                info.horizontal = from_wkt(def.wkt).ok().and_then(|w| w.horizontal);
                info.source = format!("unit of EPSG:{code} (GeoTIFF ProjectedCSTypeGeoKey)");
            }
        }
    }
    info.vertical = u16_key(4099).and_then(|code| unit_key(code, "VerticalUnitsGeoKey", notes));
    info
}

/// The unit of a GeoTIFF unit key's EPSG code; a code that is no length unit is left out,
/// with a note.
fn unit_key(code: u16, key: &str, notes: &mut Vec<String>) -> Option<LinearUnit> {
    let unit = LinearUnit::from_epsg(code);
    if unit.is_none() {
        notes.push(format!(
            "its GeoTIFF {key} holds {code}, which is not a length unit (left out)"
        ));
    }
    unit
}

/// Metres per coordinate unit of a file: its CRS's horizontal unit, else 1 (metres, also for
/// a CRS that cannot be read: the pipeline reports those; tools that only need a length
/// scale, such as `thin` and `eval`, go on in metres).
pub fn metres_per_unit(header: &las::Header) -> f64 {
    CrsInfo::of_header(header)
        .horizontal
        .map_or(1.0, |u| u.metres)
}

/// A WKT element: keyword and arguments (text, numbers and enumerations are all kept as text).
#[derive(Debug)]
struct Node {
    key: String,
    args: Vec<Arg>,
}

#[derive(Debug)]
enum Arg {
    Text(String),
    Node(Node),
}

impl Node {
    fn children(&self) -> impl Iterator<Item = &Node> {
        self.args.iter().filter_map(|a| match a {
            Arg::Node(n) => Some(n),
            Arg::Text(_) => None,
        })
    }

    fn child(&self, keys: &[&str]) -> Option<&Node> {
        self.children().find(|n| keys.contains(&n.key.as_str()))
    }

    /// A `UNIT["name", metres]` / `LENGTHUNIT[...]` element as a unit.
    fn as_unit(&self) -> Option<LinearUnit> {
        let name = match self.args.first()? {
            Arg::Text(t) => t.clone(),
            Arg::Node(_) => return None,
        };
        let metres: f64 = match self.args.get(1)? {
            Arg::Text(t) => t.parse().ok()?,
            Arg::Node(_) => return None,
        };
        (metres.is_finite() && metres > 0.0).then_some(LinearUnit { name, metres })
    }
}

/// Deepest nesting accepted (real CRSs nest about 6 deep).
const MAX_DEPTH: usize = 32;

fn parse(text: &str) -> Result<Node, String> {
    let b = text.as_bytes();
    let mut i = 0;
    let node = parse_node(b, &mut i, 0)?;
    Ok(node)
}

fn skip_ws(b: &[u8], i: &mut usize) {
    while *i < b.len() && b[*i].is_ascii_whitespace() {
        *i += 1;
    }
}

fn parse_node(b: &[u8], i: &mut usize, depth: usize) -> Result<Node, String> {
    if depth > MAX_DEPTH {
        return Err(format!("nested deeper than {MAX_DEPTH} levels"));
    }
    skip_ws(b, i);
    let start = *i;
    while *i < b.len() && (b[*i].is_ascii_alphanumeric() || b[*i] == b'_') {
        *i += 1;
    }
    let key = String::from_utf8_lossy(&b[start..*i]).to_ascii_uppercase();
    skip_ws(b, i);
    if key.is_empty() || *i >= b.len() || !(b[*i] == b'[' || b[*i] == b'(') {
        return Err(format!("expected KEYWORD[ at byte {start}"));
    }
    let close = if b[*i] == b'[' { b']' } else { b')' };
    *i += 1;
    let mut args = Vec::new();
    loop {
        skip_ws(b, i);
        if *i >= b.len() {
            return Err(format!("{key}[ is not closed"));
        }
        if b[*i] == close && args.is_empty() {
            *i += 1;
            break;
        }
        if b[*i] == b'"' {
            *i += 1;
            let mut s = Vec::new();
            loop {
                match b.get(*i) {
                    None => return Err("unterminated quoted text".into()),
                    // "" inside quotes is a quote.
                    Some(b'"') if b.get(*i + 1) == Some(&b'"') => {
                        s.push(b'"');
                        *i += 2;
                    }
                    Some(b'"') => {
                        *i += 1;
                        break;
                    }
                    Some(c) => {
                        s.push(*c);
                        *i += 1;
                    }
                }
            }
            args.push(Arg::Text(String::from_utf8_lossy(&s).into_owned()));
        } else {
            let start = *i;
            while *i < b.len() && !matches!(b[*i], b',' | b'[' | b'(' | b']' | b')') {
                *i += 1;
            }
            skip_ws(b, i);
            if *i < b.len() && (b[*i] == b'[' || b[*i] == b'(') {
                *i = start;
                args.push(Arg::Node(parse_node(b, i, depth + 1)?));
            } else {
                let t = String::from_utf8_lossy(&b[start..*i]).trim().to_string();
                if t.is_empty() {
                    return Err(format!("{key}[: empty value at byte {start}"));
                }
                args.push(Arg::Text(t));
            }
        }
        skip_ws(b, i);
        match b.get(*i) {
            Some(b',') => *i += 1,
            Some(c) if *c == close => {
                *i += 1;
                break;
            }
            _ => {
                return Err(format!(
                    "{key}[: expected ',' or the closing bracket at byte {i}"
                ))
            }
        }
    }
    Ok(Node { key, args })
}

const PROJECTED: &[&str] = &["PROJCS", "PROJCRS", "PROJECTEDCRS"];
const GEOGRAPHIC: &[&str] = &[
    "GEOGCS",
    "GEOGCRS",
    "GEOGRAPHICCRS",
    "GEODCRS",
    "GEODETICCRS",
    "GEOCCS",
];

/// A geodetic CRS element that is geocentric: WKT 1's `GEOCCS`, or a WKT 2 geodetic CRS
/// whose coordinate system is Cartesian.
fn is_geocentric(crs: &Node) -> bool {
    crs.key == "GEOCCS"
        || (["GEODCRS", "GEODETICCRS"].contains(&crs.key.as_str())
            && crs.child(&["CS"]).is_some_and(|cs| {
                matches!(cs.args.first(), Some(Arg::Text(t)) if t.eq_ignore_ascii_case("cartesian"))
            }))
}

/// The name of a CRS element (its first, quoted argument).
fn name_of(crs: &Node) -> Option<String> {
    match crs.args.first()? {
        Arg::Text(t) if !t.is_empty() => Some(t.clone()),
        _ => None,
    }
}
const VERTICAL: &[&str] = &["VERT_CS", "VERTCS", "VERTCRS", "VERTICALCRS"];
const UNITS: &[&str] = &["UNIT", "LENGTHUNIT"];

/// The unit of a CRS element: its own `UNIT`/`LENGTHUNIT`, else (WKT2) the first axis's.
fn unit_of(crs: &Node) -> Option<LinearUnit> {
    if let Some(u) = crs.child(UNITS) {
        return u.as_unit();
    }
    crs.children()
        .filter(|n| n.key == "AXIS")
        .find_map(|a| a.child(UNITS))
        .and_then(Node::as_unit)
}

fn epsg_of(crs: &Node) -> Option<u16> {
    let id = crs.child(&["AUTHORITY", "ID"])?;
    match (id.args.first(), id.args.get(1)) {
        (Some(Arg::Text(a)), Some(Arg::Text(c))) if a.eq_ignore_ascii_case("EPSG") => {
            c.trim().parse().ok()
        }
        _ => None,
    }
}

/// Units (and EPSG code) of a WKT 1 or WKT 2 CRS; compound CRSs give a vertical unit too.
fn from_wkt(text: &str) -> Result<CrsInfo, String> {
    let root = parse(text)?;
    let (horizontal, vertical) = if ["COMPD_CS", "COMPOUNDCRS"].contains(&root.key.as_str()) {
        let h = root
            .children()
            .find(|n| PROJECTED.contains(&n.key.as_str()) || GEOGRAPHIC.contains(&n.key.as_str()));
        (h, root.child(VERTICAL))
    } else if VERTICAL.contains(&root.key.as_str()) {
        (None, Some(&root))
    } else {
        (Some(&root), None)
    };
    let mut info = CrsInfo {
        name: name_of(&root),
        ..CrsInfo::default()
    };
    if let Some(h) = horizontal {
        if is_geocentric(h) {
            // Geocentric coordinates are metres (the unit is the CRS's own).
            info.geocentric = true;
            info.horizontal = unit_of(h);
        } else if GEOGRAPHIC.contains(&h.key.as_str()) {
            info.geographic = true;
        } else if PROJECTED.contains(&h.key.as_str()) {
            info.horizontal = unit_of(h);
        } else {
            return Err(format!("{} is not a CRS tessera knows", h.key));
        }
        info.epsg = epsg_of(h);
    }
    info.vertical = vertical.and_then(unit_of);
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wkt1_projected_feet_and_compound_vertical() {
        let wkt = r#"COMPD_CS["NAD83(HARN) / New Mexico Central (ftUS) + NAVD88 height",
            PROJCS["NAD83(HARN) / New Mexico Central (ftUS)",
              GEOGCS["NAD83(HARN)",DATUM["NAD83_High_Accuracy_Reference_Network",
                SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],
                UNIT["degree",0.0174532925199433]],
              PROJECTION["Transverse_Mercator"],PARAMETER["false_easting",1640416.667],
              UNIT["US survey foot",0.3048006096012192,AUTHORITY["EPSG","9003"]],
              AUTHORITY["EPSG","2903"]],
            VERT_CS["NAVD88 height",VERT_DATUM["North American Vertical Datum 1988",2005],
              UNIT["metre",1]]]"#;
        let info = from_wkt(wkt).unwrap();
        assert_eq!(info.epsg, Some(2903));
        let h = info.horizontal.unwrap();
        assert!(h.same_as(&LinearUnit::us_survey_foot()), "{h:?}");
        assert!(info.vertical.unwrap().is_metre());
        assert!(!info.geographic);
    }

    #[test]
    fn wkt2_units_from_the_axes_not_the_conversion() {
        let wkt = r#"PROJCRS["NAD83 / Oregon GIC Lambert (ft)",
          BASEGEOGCRS["NAD83",DATUM["North American Datum 1983",
            ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],
            ANGLEUNIT["degree",0.0174532925199433]],
          CONVERSION["Oregon GIC Lambert (ft)",METHOD["Lambert Conic Conformal (2SP)"],
            PARAMETER["False easting",1312335.958,LENGTHUNIT["metre",1]]],
          CS[Cartesian,2],
            AXIS["easting (X)",east,ORDER[1],LENGTHUNIT["foot",0.3048]],
            AXIS["northing (Y)",north,ORDER[2],LENGTHUNIT["foot",0.3048]],
          ID["EPSG",2992]]"#;
        let info = from_wkt(wkt).unwrap();
        assert_eq!(info.epsg, Some(2992));
        assert!(info.horizontal.unwrap().same_as(&LinearUnit::foot()));
        assert!(info.vertical.is_none());
    }

    #[test]
    fn geographic_and_hostile_wkt() {
        let g = from_wkt(crs_definitions::from_code(4326).unwrap().wkt).unwrap();
        assert!(g.geographic && g.horizontal.is_none());
        let deep = "A[".repeat(100_000);
        assert!(from_wkt(&deep).unwrap_err().contains("nested deeper"));
        for bad in [
            "",
            "PROJCS",
            "PROJCS[\"x\"",
            "PROJCS[\"x,1]",
            "[]",
            "PROJCS[\"a\",,]",
        ] {
            assert!(from_wkt(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn epsg_table_gives_units_and_wkt() {
        let ft = from_wkt(crs_definitions::from_code(2903).unwrap().wkt).unwrap();
        assert!(ft
            .horizontal
            .unwrap()
            .same_as(&LinearUnit::us_survey_foot()));
        let m = from_wkt(crs_definitions::from_code(28992).unwrap().wkt).unwrap();
        assert!(m.horizontal.unwrap().is_metre());
    }
}
