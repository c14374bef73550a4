//! Areas left out of scoring: GeoJSON polygons (`tessera eval labels --exclude FILE`), e.g.
//! a block a producer left unclassified. Reads `Polygon` and `MultiPolygon` geometries, bare
//! or in a `Feature` / `FeatureCollection`, with holes; coordinates are taken as x, y in the
//! data's own CRS (no reprojection: write the polygons in the tiles' CRS).

use crate::error::{Error, Result};
use serde_json::Value;
use std::path::Path;

/// One polygon: an outer ring and its holes, each a closed list of (x, y).
#[derive(Debug, Clone, PartialEq)]
struct Polygon {
    rings: Vec<Vec<[f64; 2]>>,
    /// Bounding box of the outer ring: [min x, min y, max x, max y].
    bbox: [f64; 4],
}

/// A set of polygons; a point is inside the set when it is inside any of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Polygons {
    polygons: Vec<Polygon>,
}

/// Even-odd crossing test of (x, y) against one ring.
fn in_ring(ring: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut inside = false;
    let n = ring.len();
    let mut j = n - 1;
    for i in 0..n {
        let (a, b) = (ring[i], ring[j]);
        if (a[1] > y) != (b[1] > y) {
            let t = (y - a[1]) / (b[1] - a[1]);
            if x < a[0] + t * (b[0] - a[0]) {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

impl Polygons {
    /// Reads the polygons of a GeoJSON file.
    pub fn from_geojson(path: &Path) -> Result<Polygons> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let v: Value = serde_json::from_str(&text)
            .map_err(|e| Error::bad_input(path, format!("not JSON: {e}")))?;
        let mut out = Polygons::default();
        out.add(&v).map_err(|e| Error::bad_input(path, e))?;
        if out.polygons.is_empty() {
            return Err(Error::bad_input(path, "no Polygon or MultiPolygon in it"));
        }
        Ok(out)
    }

    fn add(&mut self, v: &Value) -> std::result::Result<(), String> {
        match v["type"].as_str() {
            Some("FeatureCollection") => {
                let features = v["features"]
                    .as_array()
                    .ok_or("a FeatureCollection without \"features\"")?;
                for f in features {
                    self.add(f)?;
                }
                Ok(())
            }
            Some("Feature") => self.add(&v["geometry"]),
            Some("Polygon") => self.polygon(&v["coordinates"]),
            Some("MultiPolygon") => {
                let parts = v["coordinates"]
                    .as_array()
                    .ok_or("a MultiPolygon without coordinates")?;
                for p in parts {
                    self.polygon(p)?;
                }
                Ok(())
            }
            Some(other) => Err(format!(
                "geometry type {other} cannot exclude an area (Polygon or MultiPolygon)"
            )),
            None => Err("a GeoJSON object without \"type\"".into()),
        }
    }

    fn polygon(&mut self, coords: &Value) -> std::result::Result<(), String> {
        let rings = coords
            .as_array()
            .ok_or("polygon coordinates not an array")?;
        let mut out = Vec::with_capacity(rings.len());
        for r in rings {
            let pts = r.as_array().ok_or("a ring is not an array")?;
            let mut ring = Vec::with_capacity(pts.len());
            for p in pts {
                let xy = p.as_array().ok_or("a position is not an array")?;
                let c = |k: usize| xy.get(k).and_then(Value::as_f64).filter(|v| v.is_finite());
                match (c(0), c(1)) {
                    (Some(x), Some(y)) => ring.push([x, y]),
                    _ => return Err(format!("bad position {p}")),
                }
            }
            if ring.len() > 1 && ring.first() == ring.last() {
                ring.pop();
            }
            if ring.len() < 3 {
                return Err("a ring with fewer than 3 distinct positions".into());
            }
            out.push(ring);
        }
        let Some(outer) = out.first() else {
            return Err("a polygon without rings".into());
        };
        let mut bbox = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for p in outer {
            bbox = [
                bbox[0].min(p[0]),
                bbox[1].min(p[1]),
                bbox[2].max(p[0]),
                bbox[3].max(p[1]),
            ];
        }
        self.polygons.push(Polygon { rings: out, bbox });
        Ok(())
    }

    /// Whether (x, y) lies inside any polygon (inside its outer ring, outside its holes).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        self.polygons.iter().any(|p| {
            let b = p.bbox;
            x >= b[0]
                && x <= b[2]
                && y >= b[1]
                && y <= b[3]
                && in_ring(&p.rings[0], x, y)
                && !p.rings[1..].iter().any(|h| in_ring(h, x, y))
        })
    }

    /// Number of polygons.
    pub fn len(&self) -> usize {
        self.polygons.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.polygons.is_empty()
    }

    /// Another set's polygons added to these.
    pub fn extend(&mut self, other: Polygons) {
        self.polygons.extend(other.polygons);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> std::result::Result<Polygons, String> {
        let mut p = Polygons::default();
        p.add(&serde_json::from_str(s).unwrap())?;
        Ok(p)
    }

    #[test]
    fn l_shape_with_a_hole_and_a_second_polygon() {
        let p = parse(
            r#"{"type":"FeatureCollection","features":[
              {"type":"Feature","properties":{},"geometry":{"type":"Polygon","coordinates":[
                [[0,0],[10,0],[10,4],[4,4],[4,10],[0,10],[0,0]],
                [[1,1],[2,1],[2,2],[1,2],[1,1]]]}},
              {"type":"Feature","geometry":{"type":"MultiPolygon","coordinates":[
                [[[20,20],[22,20],[22,22],[20,22]]]]}}]}"#,
        )
        .unwrap();
        assert_eq!(p.len(), 2);
        assert!(p.contains(8.0, 2.0)); // foot of the L
        assert!(p.contains(2.0, 8.0)); // stem
        assert!(!p.contains(8.0, 8.0)); // the notch
        assert!(!p.contains(1.5, 1.5)); // the hole
        assert!(p.contains(21.0, 21.0));
        assert!(!p.contains(-1.0, 5.0) && !p.contains(30.0, 21.0));
    }

    #[test]
    fn bad_geometries_are_errors() {
        assert!(parse(r#"{"type":"Point","coordinates":[1,2]}"#).is_err());
        assert!(parse(r#"{"type":"Polygon","coordinates":[[[0,0],[1,1],[0,0]]]}"#).is_err());
        assert!(parse(r#"{"type":"Polygon","coordinates":[[[0,0],[1,"a"],[2,0]]]}"#).is_err());
        assert!(parse(r#"{"features":[]}"#).is_err());
    }
}
