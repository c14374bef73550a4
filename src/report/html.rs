//! `report.html`: one self-contained page (images embedded as PNG data URIs, no script, no
//! network) showing a finished run: overview rasters with a class legend and the tile grid,
//! the error map and confusion matrix when the tiles carry truth, the slowest tiles, stage
//! costs, memory against the budget and the stitching figures. Built from the output
//! directory alone (`summary.json` and the tiles), so `tessera report DIR` and the run itself
//! produce the same page.

use super::overview::{self, Geometry, Overview, TileExtent};
use crate::error::{Error, Result};
use serde_json::Value;
use std::collections::HashSet;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// File name of the report in an output directory.
pub const REPORT: &str = "report.html";

/// What building the report cost.
#[derive(Debug, Clone, Copy)]
pub struct ReportCost {
    /// Wall seconds.
    pub seconds: f64,
    /// Points rasterised.
    pub points: u64,
    /// Raster cells.
    pub pixels: usize,
    /// Tiles decoded from their files (not drawn while the run wrote them).
    pub decoded_tiles: usize,
    /// The raster drawn.
    pub geometry: Geometry,
}

/// Most tiles outlined on the class map: beyond this the outlines no longer read at the
/// raster's resolution, and the page would grow with the region.
const OUTLINE_MAX_TILES: usize = 2000;
/// Tiles listed in the slowest-tiles table.
const SLOWEST: usize = 15;

/// One tile of the summary, as the page shows it.
struct TileRow {
    name: String,
    points: u64,
    buffer_points: u64,
    /// Stage seconds summed.
    seconds: f64,
}

/// What the page keeps of the tiles, whatever their number: the count, the slowest, and the
/// outlines of a region of at most [`OUTLINE_MAX_TILES`] tiles.
#[derive(Default)]
struct TileBook {
    count: usize,
    slowest: Vec<TileRow>,
    outlines: Vec<(TileExtent, f64)>,
}

impl TileBook {
    fn add(&mut self, row: TileRow, extent: Option<TileExtent>) {
        self.count += 1;
        if let Some(e) = extent {
            self.outlines.push((e, row.seconds));
        }
        if self.count > OUTLINE_MAX_TILES {
            self.outlines = Vec::new();
        }
        let slower =
            |a: &TileRow, b: &TileRow| b.seconds.total_cmp(&a.seconds).then(a.name.cmp(&b.name));
        let at = self
            .slowest
            .binary_search_by(|r| slower(r, &row))
            .unwrap_or_else(|i| i);
        if at < SLOWEST {
            self.slowest.insert(at, row);
            self.slowest.truncate(SLOWEST);
        }
    }
}

/// A tile row's name and file (plain file names inside the directory only: a summary is
/// input).
fn name_file(t: &Value) -> Option<(&str, &str)> {
    let file = t.get("file")?.as_str()?;
    if file.contains('/') || file.starts_with('.') || file.is_empty() {
        return None;
    }
    Some((t.get("name")?.as_str()?, file))
}

/// Builds the report page of the run in `dir` whose summary is `summary`. `drawn` is what
/// the run drew while writing (its raster and the tiles in it); the other tiles of the
/// summary are decoded from their files, into the raster `summary.report_raster` names (else
/// one covering the tiles). The tiles are read from the summary's tile table one at a time
/// (two passes when the raster must first be sized), so memory is the raster and a batch of
/// tiles however large the region.
pub fn build(
    dir: &Path,
    summary: &Value,
    drawn: Option<(Overview, HashSet<String>)>,
    w: &mut dyn std::io::Write,
) -> Result<ReportCost> {
    let t0 = Instant::now();
    let (mut ov, done) = match drawn {
        Some(d) => d,
        None => {
            let recorded = summary
                .get("report_raster")
                .and_then(|v| serde_json::from_value::<Geometry>(v.clone()).ok())
                .filter(Geometry::is_sane);
            let g = match recorded {
                Some(g) => g,
                None => {
                    let mut b = [
                        f64::INFINITY,
                        f64::INFINITY,
                        f64::NEG_INFINITY,
                        f64::NEG_INFINITY,
                    ];
                    super::for_each_tile(dir, summary, |t| {
                        let Some((name, file)) = name_file(t) else {
                            return Ok(());
                        };
                        for e in overview::tile_extents(dir, &[(name.into(), file.into())])? {
                            if e.points > 0 {
                                b = [
                                    b[0].min(e.bounds[0]),
                                    b[1].min(e.bounds[1]),
                                    b[2].max(e.bounds[2]),
                                    b[3].max(e.bounds[3]),
                                ];
                            }
                        }
                        Ok(())
                    })?;
                    Geometry::for_bounds(b)
                }
            };
            (Overview::with_geometry(g), HashSet::new())
        }
    };
    let mut book = TileBook::default();
    let mut todo: Vec<TileExtent> = Vec::new();
    let mut decoded = 0;
    super::for_each_tile(dir, summary, |t| {
        let Some((name, file)) = name_file(t) else {
            return Ok(());
        };
        let row = TileRow {
            name: name.to_string(),
            points: num(t.get("points")) as u64,
            buffer_points: num(t.get("buffer_points")) as u64,
            seconds: t
                .get("seconds")
                .and_then(Value::as_object)
                .map(|o| o.values().filter_map(Value::as_f64).sum())
                .unwrap_or(0.0),
        };
        let outline = book.count < OUTLINE_MAX_TILES;
        let extent = if outline || !done.contains(name) {
            overview::tile_extents(dir, &[(name.into(), file.into())])?.pop()
        } else {
            None
        };
        if let Some(e) = extent.as_ref().filter(|_| !done.contains(name)) {
            todo.push(e.clone());
            if todo.len() >= 64 {
                ov.add_tiles(&todo)?;
                decoded += todo.len();
                todo.clear();
            }
        }
        book.add(row, extent.filter(|_| outline));
        Ok(())
    })?;
    ov.add_tiles(&todo)?;
    decoded += todo.len();
    page(dir, summary, &ov, &book, w)?;
    let cost = ReportCost {
        seconds: t0.elapsed().as_secs_f64(),
        points: ov.points,
        pixels: ov.width * ov.height,
        decoded_tiles: decoded,
        geometry: ov.geometry(),
    };
    Ok(cost)
}

/// Reads `dir/summary.json` and rewrites `dir/report.html` (atomically, recorded in the run's
/// journal).
pub fn regenerate(dir: &Path) -> Result<ReportCost> {
    let spath = dir.join(crate::io::workspace::SUMMARY);
    let text = std::fs::read_to_string(&spath).map_err(|e| Error::io(&spath, e))?;
    let summary: Value = serde_json::from_str(&text).map_err(|e| Error::OutputDir {
        path: dir.to_path_buf(),
        reason: format!("{} is not a tessera run summary: {e}", spath.display()),
        usage: false,
    })?;
    let mut html = Vec::new();
    let cost = build(dir, &summary, None, &mut html)?;
    crate::io::workspace::rewrite_in_finished_run(dir, REPORT, &html)?;
    Ok(cost)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn num(v: Option<&Value>) -> f64 {
    v.and_then(Value::as_f64).unwrap_or(0.0)
}

fn thousands(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The page as it is written: text goes straight to the output, so the page is never held
/// whole (a large region's report is tens of MB, nearly all of it images). The first write
/// error is kept and returned at the end.
struct Page<'w> {
    w: &'w mut dyn std::io::Write,
    err: Option<std::io::Error>,
}

impl std::fmt::Write for Page<'_> {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.bytes(s.as_bytes());
        Ok(())
    }
}

impl Page<'_> {
    fn bytes(&mut self, b: &[u8]) {
        if self.err.is_none() {
            if let Err(e) = self.w.write_all(b) {
                self.err = Some(e);
            }
        }
    }

    fn push_str(&mut self, s: &str) {
        self.bytes(s.as_bytes());
    }

    /// A PNG as a data URI, base64-encoded on the way out.
    fn data_uri(&mut self, png: &[u8]) {
        self.push_str("data:image/png;base64,");
        if self.err.is_none() {
            let mut enc = base64::write::EncoderWriter::new(
                &mut *self.w,
                &base64::engine::general_purpose::STANDARD,
            );
            let res =
                std::io::Write::write_all(&mut enc, png).and_then(|_| enc.finish().map(|_| ()));
            if let Err(e) = res {
                self.err = Some(e);
            }
        }
    }
}

const STYLE: &str = "body{font:14px/1.45 system-ui,sans-serif;margin:24px;color:#222;max-width:1400px}\
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ddd}\
table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}\
th{background:#f3f3f3}td.l,th.l{text-align:left}.kv td:first-child{text-align:left;color:#555}\
figure{margin:10px 0}figcaption{color:#555;margin:4px 0}\
.map{position:relative;width:100%}.map img{width:100%;display:block;image-rendering:pixelated;border:1px solid #ccc}\
.map svg{position:absolute;left:0;top:0;width:100%;height:100%}\
.legend{display:flex;flex-wrap:wrap;gap:6px 16px;margin:6px 0;padding:0;list-style:none}\
.legend li{display:flex;align-items:center;gap:6px}.sw{width:14px;height:14px;border:1px solid #888;display:inline-block}\
.bar{background:#eee;width:420px;height:16px;position:relative;border:1px solid #bbb}\
.bar span{position:absolute;left:0;top:0;bottom:0;background:#4a8}.over span{background:#d44}\
td.hot{background:#fde2e2}";

/// The page.
fn page(
    dir: &Path,
    s: &Value,
    ov: &Overview,
    tiles: &TileBook,
    w: &mut dyn std::io::Write,
) -> Result<()> {
    let mut h = Page { w, err: None };
    let _ = write!(
        h,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>tessera report — {}</title><style>{STYLE}</style></head><body>",
        esc(&dir.display().to_string())
    );
    let _ = write!(
        h,
        "<h1>tessera run report</h1><p>{} · tessera {}</p>",
        esc(&dir.display().to_string()),
        esc(s.get("version").and_then(Value::as_str).unwrap_or("?"))
    );
    run_table(&mut h, s);
    maps(&mut h, ov, tiles)?;
    if ov.truth_field.is_some() {
        confusion(&mut h, ov);
    }
    tile_table(&mut h, tiles);
    stage_table(&mut h, s);
    memory(&mut h, s);
    if let Some(st) = s.get("stitch").and_then(Value::as_object) {
        h.push_str("<h2>Stitching across tile borders</h2><table class=\"kv\">");
        for (k, v) in st {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td></tr>",
                esc(k),
                esc(&v.to_string())
            );
        }
        h.push_str("</table>");
    }
    h.push_str("</body></html>\n");
    match h.err {
        Some(e) => Err(Error::io(dir.join(REPORT), e)),
        None => Ok(()),
    }
}

fn run_table(h: &mut Page<'_>, s: &Value) {
    let secs = s.get("seconds");
    let total = num(secs.and_then(|v| v.get("total")));
    let pin = num(s.get("points_in")) as u64;
    let rows: Vec<(&str, String)> = vec![
        ("inputs", format!("{}", num(s.get("inputs")))),
        (
            "points in / out",
            format!(
                "{} / {}",
                thousands(pin),
                thousands(num(s.get("points_out")) as u64)
            ),
        ),
        (
            "tiles (grid tiles split)",
            format!("{} ({})", num(s.get("tiles")), num(s.get("tiles_split"))),
        ),
        (
            "wall time",
            format!(
                "{total:.1} s = {:.3} M points/s",
                pin as f64 / total.max(1e-9) / 1e6
            ),
        ),
        (
            "peak RSS / memory budget",
            format!(
                "{:.0} / {} MiB",
                num(s.get("peak_rss_mb")),
                num(s.get("memory_budget_mb"))
            ),
        ),
        ("overlap buffer", format!("{} m", num(s.get("buffer_m")))),
    ];
    h.push_str("<table class=\"kv\">");
    for (k, v) in rows {
        let _ = write!(h, "<tr><td>{k}</td><td>{}</td></tr>", esc(&v));
    }
    if let Some(f) = s.get("failed_tiles").and_then(Value::as_array) {
        let _ = write!(h, "<tr><td>failed tiles</td><td>{}</td></tr>", f.len());
    }
    h.push_str("</table>");
}

fn maps(h: &mut Page<'_>, ov: &Overview, tiles: &TileBook) -> Result<()> {
    let _ = write!(
        h,
        "<h2>Overview</h2><p>{} × {} cells of {:.2} m; each cell shows its highest point. {} points.</p>",
        ov.width,
        ov.height,
        ov.cell,
        thousands(ov.points)
    );
    // Legend: the classes present, most points first.
    let mut present: Vec<(u8, u64)> = ov.class_points.iter().map(|(c, n)| (*c, *n)).collect();
    present.sort_by_key(|p| std::cmp::Reverse(p.1));
    h.push_str("<ul class=\"legend\" id=\"legend\">");
    for (c, n) in &present {
        let [r, g, b] = overview::class_colour(*c);
        let _ = write!(
            h,
            "<li data-class=\"{c}\"><span class=\"sw\" style=\"background:rgb({r},{g},{b})\"></span>{c} {} ({:.1} %)</li>",
            overview::class_name(*c),
            100.0 * *n as f64 / ov.points.max(1) as f64
        );
    }
    h.push_str("</ul>");
    let grid = tile_grid_svg(ov, tiles);
    let png = |rgb: Vec<u8>| overview::png(&rgb, ov.width, ov.height);
    figure(
        h,
        "overview-class",
        "Classes, with the tile grid (split tiles dashed orange)",
        &png(ov.class_rgb())?,
        &grid,
    );
    if ov.has_segments {
        figure(
            h,
            "overview-segment",
            "Segments in random colours (grey: in no segment)",
            &png(ov.segment_rgb())?,
            "",
        );
    }
    let (lo, hi) = ov.height_range();
    figure(
        h,
        "overview-height",
        &format!(
            "Height of the highest point, {:.1} (blue) to {:.1} (yellow), hillshaded",
            // Rounded first, so a height of -0.04 does not print as "-0.0".
            (lo * 10.0).round() / 10.0 + 0.0,
            (hi * 10.0).round() / 10.0 + 0.0
        ),
        &png(ov.height_rgb())?,
        "",
    );
    if let Some(rgb) = ov.error_rgb() {
        figure(
            h,
            "overview-errors",
            &format!(
                "Errors against the truth attribute \"{}\": cells with wrong points in red (darker: a larger share wrong), right cells grey",
                esc(ov.truth_field.as_deref().unwrap_or(""))
            ),
            &png(rgb)?,
            "",
        );
    }
    Ok(())
}

fn figure(h: &mut Page<'_>, id: &str, caption: &str, png: &[u8], overlay: &str) {
    let _ = write!(
        h,
        "<figure id=\"{id}\"><figcaption>{caption}</figcaption><div class=\"map\"><img alt=\"{id}\" src=\""
    );
    h.data_uri(png);
    let _ = write!(h, "\">{overlay}</div></figure>");
}

fn tile_grid_svg(ov: &Overview, tiles: &TileBook) -> String {
    if tiles.outlines.is_empty() {
        return String::new();
    }
    let mut g = format!(
        "<svg viewBox=\"0 0 {} {}\" preserveAspectRatio=\"none\">",
        ov.width, ov.height
    );
    for (t, secs) in &tiles.outlines {
        let [x, y, w, hh] = ov.pixel_rect(t.bounds);
        let split = t.name.contains("_q");
        let _ = write!(
            g,
            "<rect x=\"{x:.1}\" y=\"{y:.1}\" width=\"{w:.1}\" height=\"{hh:.1}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1\" vector-effect=\"non-scaling-stroke\"{}><title>{}: {} points, {secs:.2} s</title></rect>",
            if split { "#e08000" } else { "#000" },
            if split { " stroke-dasharray=\"4 3\"" } else { "" },
            esc(&t.name),
            thousands(t.points)
        );
    }
    g.push_str("</svg>");
    g
}

fn tile_table(h: &mut Page<'_>, tiles: &TileBook) {
    let _ = write!(
        h,
        "<h2>Tiles</h2><p>{} tiles; the {} slowest (stage seconds summed).{}</p><table><tr><th class=\"l\">tile</th><th>core points</th><th>buffer points</th><th>seconds</th><th>µs per core point</th></tr>",
        tiles.count,
        tiles.slowest.len(),
        if tiles.count > OUTLINE_MAX_TILES {
            format!(" Tile outlines are drawn for regions of at most {OUTLINE_MAX_TILES} tiles; every tile is listed in the tile table ({}).", super::TILE_TABLE)
        } else {
            String::new()
        }
    );
    for r in &tiles.slowest {
        let _ =
            write!(
            h,
            "<tr><td class=\"l\">{}{}</td><td>{}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td></tr>",
            esc(&r.name),
            if r.name.contains("_q") { " (split)" } else { "" },
            thousands(r.points),
            thousands(r.buffer_points),
            r.seconds,
            r.seconds * 1e6 / r.points.max(1) as f64
        );
    }
    h.push_str("</table>");
}

fn stage_table(h: &mut Page<'_>, s: &Value) {
    let Some(st) = s.get("stages").and_then(Value::as_object) else {
        return;
    };
    h.push_str("<h2>Stages</h2><table><tr><th class=\"l\">stage</th><th>points worked on</th><th>per input point</th><th>wall s (summed over tiles)</th><th>CPU s</th><th>CPU µs per input point</th><th>peak MiB on one tile</th></tr>");
    for (k, v) in st {
        let _ = write!(
            h,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.1}</td></tr>",
            esc(k),
            thousands(num(v.get("points")) as u64),
            num(v.get("points_per_input_point")),
            num(v.get("seconds")),
            num(v.get("cpu_seconds")),
            num(v.get("cpu_us_per_input_point")),
            num(v.get("peak_bytes")) / 1048576.0
        );
    }
    h.push_str("</table>");
    if let Some(secs) = s.get("seconds").and_then(Value::as_object) {
        h.push_str("<p>Phases, wall seconds: ");
        let parts: Vec<String> = secs
            .iter()
            .filter(|(k, _)| !k.starts_with("stage_"))
            .map(|(k, v)| format!("{} {:.2}", esc(k), v.as_f64().unwrap_or(0.0)))
            .collect();
        h.push_str(&parts.join(" · "));
        h.push_str("</p>");
    }
}

fn memory(h: &mut Page<'_>, s: &Value) {
    let peak = num(s.get("peak_rss_mb"));
    let budget = num(s.get("memory_budget_mb"));
    let pct = if budget > 0.0 {
        100.0 * peak / budget
    } else {
        0.0
    };
    let _ = write!(
        h,
        "<h2>Memory</h2><p>Peak resident memory {peak:.0} MiB of the {budget:.0} MiB budget ({pct:.0} %).</p><div class=\"bar{}\"><span style=\"width:{:.1}%\"></span></div>",
        if pct > 100.0 { " over" } else { "" },
        pct.min(100.0)
    );
    memory_chart(h, s, budget);
    if let Some(b) = s.get("budget").and_then(Value::as_object) {
        h.push_str("<table class=\"kv\">");
        for key in [
            "workers",
            "tiles_in_flight",
            "max_tile_points",
            "bytes_per_tile_point",
            "tile_bytes",
            "stitch_bytes",
            "output_bytes",
            "spill_bytes",
        ] {
            if let Some(v) = b.get(key) {
                let _ = write!(h, "<tr><td>{key}</td><td>{}</td></tr>", esc(&v.to_string()));
            }
        }
        h.push_str("</table>");
    }
}

fn confusion(h: &mut Page<'_>, ov: &Overview) {
    let mut truth: Vec<u8> = ov.confusion.keys().map(|k| k.0).collect();
    truth.sort_unstable();
    truth.dedup();
    let mut res: Vec<u8> = ov.confusion.keys().map(|k| k.1).collect();
    res.sort_unstable();
    res.dedup();
    let right: u64 = ov
        .confusion
        .iter()
        .filter(|(k, _)| k.0 == k.1)
        .map(|(_, n)| n)
        .sum();
    let total: u64 = ov.confusion.values().sum();
    let _ = write!(
        h,
        "<h2>Confusion matrix</h2><p>Rows: truth (\"{}\"), columns: result. {:.2} % of {} points right.</p><table id=\"confusion\"><tr><th class=\"l\">truth \\ result</th>",
        esc(ov.truth_field.as_deref().unwrap_or("")),
        100.0 * right as f64 / total.max(1) as f64,
        thousands(total)
    );
    for r in &res {
        let _ = write!(h, "<th>{r}</th>");
    }
    h.push_str("<th>recall</th></tr>");
    for t in &truth {
        let row: u64 = res
            .iter()
            .map(|r| ov.confusion.get(&(*t, *r)).copied().unwrap_or(0))
            .sum();
        let _ = write!(
            h,
            "<tr><th class=\"l\">{t} {}</th>",
            overview::class_name(*t)
        );
        for r in &res {
            let n = ov.confusion.get(&(*t, *r)).copied().unwrap_or(0);
            let hot = t != r && n as f64 > 0.01 * row as f64;
            let _ = write!(
                h,
                "<td{}>{}</td>",
                if hot { " class=\"hot\"" } else { "" },
                thousands(n)
            );
        }
        let diag = ov.confusion.get(&(*t, *t)).copied().unwrap_or(0);
        let _ = write!(
            h,
            "<td>{:.1} %</td></tr>",
            100.0 * diag as f64 / row.max(1) as f64
        );
    }
    h.push_str("</table>");
}

/// Resident memory over the run (summary `memory_timeline`) against the budget, as an SVG
/// line chart.
fn memory_chart(h: &mut Page<'_>, s: &Value, budget: f64) {
    let pts: Vec<(f64, f64)> = s
        .get("memory_timeline")
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|p| Some((p.get(0)?.as_f64()?, p.get(1)?.as_f64()?)))
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .collect()
        })
        .unwrap_or_default();
    if pts.len() < 2 {
        return;
    }
    let (w, ht, pad) = (800.0, 220.0, 40.0);
    let tmax = pts.iter().map(|p| p.0).fold(1e-9, f64::max);
    let ymax = pts.iter().map(|p| p.1).fold(budget, f64::max).max(1.0) * 1.05;
    let x = |t: f64| pad + (w - 2.0 * pad) * t / tmax;
    let y = |m: f64| ht - pad + -(ht - 2.0 * pad) * m / ymax;
    let line: Vec<String> = pts
        .iter()
        .map(|p| format!("{:.1},{:.1}", x(p.0), y(p.1)))
        .collect();
    let _ = write!(
        h,
        "<figure id=\"memory\"><figcaption>Resident memory (MiB) over the run's {tmax:.0} s; dashed: the {budget:.0} MiB budget</figcaption><svg width=\"{w}\" height=\"{ht}\" viewBox=\"0 0 {w} {ht}\" style=\"border:1px solid #ccc\">\
<line x1=\"{pad}\" y1=\"{b:.1}\" x2=\"{r}\" y2=\"{b:.1}\" stroke=\"#d44\" stroke-dasharray=\"6 4\"/>\
<polyline fill=\"none\" stroke=\"#2a6\" stroke-width=\"2\" points=\"{}\"/>\
<line x1=\"{pad}\" y1=\"{base}\" x2=\"{r}\" y2=\"{base}\" stroke=\"#888\"/>\
<text x=\"{pad}\" y=\"{lbl}\" font-size=\"11\">0 s</text><text x=\"{r}\" y=\"{lbl}\" font-size=\"11\" text-anchor=\"end\">{tmax:.0} s</text>\
<text x=\"4\" y=\"{b:.1}\" font-size=\"11\">{budget:.0}</text></svg></figure>",
        line.join(" "),
        b = y(budget),
        r = w - pad,
        base = ht - pad,
        lbl = ht - pad + 14.0,
    );
}
