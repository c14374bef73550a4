//! Resumable runs (issue 20): a run killed with SIGKILL at any moment is finished by the same
//! command, with tiles byte-identical to an uninterrupted run; a run that is not the same run
//! (changed input or setting) is refused with what changed; `--restart` starts over.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// A synthetic street of `length_m` metres (4 files), default density.
fn scene(dir: &Path, length_m: u32) -> Vec<PathBuf> {
    let out = dir.join("scene");
    let o = tessera()
        .args(["-q", "synth", "--length-m", &length_m.to_string(), "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let mut files: Vec<PathBuf> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "laz"))
        .collect();
    files.sort();
    files
}

fn run_cmd(out: &Path, inputs: &[PathBuf], extra: &[&str]) -> Command {
    let mut c = tessera();
    c.args(["-q", "run"]).args(extra).arg("--out").arg(out);
    c.args(inputs);
    c
}

/// Every output file (tiles, segment tables) with its bytes; bookkeeping, the summary and
/// the report (timings) left out, but the report's images in: a resumed run draws the
/// tiles it reuses from their files, the rest while writing, and must draw the same.
/// Asserts that two runs' outputs are the same, naming the files that differ.
fn same_outputs(a: &Path, b: &Path) {
    let (a, b) = (outputs(a), outputs(b));
    let names = |v: &[(String, Vec<u8>)]| v.iter().map(|f| f.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&a), names(&b));
    let differ: Vec<&String> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.1 != y.1)
        .map(|(x, _)| &x.0)
        .collect();
    assert!(differ.is_empty(), "files differ: {differ:?}");
}

fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with(".tessera") && n != "summary.json")
        .map(|n| {
            let mut bytes = std::fs::read(dir.join(&n)).unwrap();
            if n == "report.html" {
                let page = String::from_utf8(bytes).unwrap();
                // The images (the tile grid's tooltips carry timings).
                bytes = page
                    .split(" src=\"")
                    .skip(1)
                    .map(|f| &f[..f.find('"').unwrap()])
                    .collect::<Vec<_>>()
                    .concat()
                    .into_bytes();
                assert!(!bytes.is_empty(), "report.html without pictures");
            }
            if n == "tiles.jsonl" {
                // The tile table in name order, without timings (a reused tile has none).
                fn untimed(v: &mut serde_json::Value) {
                    if let Some(o) = v.as_object_mut() {
                        o.remove("seconds");
                        o.values_mut().for_each(untimed);
                    }
                }
                let mut rows: Vec<String> = String::from_utf8(bytes)
                    .unwrap()
                    .lines()
                    .map(|l| {
                        let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
                        untimed(&mut v);
                        v.to_string()
                    })
                    .collect();
                rows.sort();
                bytes = rows.join("\n").into_bytes();
            }
            (n, bytes)
        })
        .collect();
    v.sort();
    v
}

fn journal_lines(out: &Path) -> usize {
    std::fs::read_to_string(out.join(".tessera-resume/log"))
        .map(|t| t.lines().count())
        .unwrap_or(0)
}

/// A small deterministic generator for the kill moments (seed printed on failure).
struct Lcg(u64);
impl Lcg {
    fn next_f64(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The crash-safety gate: a ≥ 5 M-point street with the default stages, killed with SIGKILL
/// at 10 random moments — each resumed run is itself killed, so kills land while inputs are
/// read, while cells are processed and while stitched tiles are written — then finished by
/// the same command: tiles byte-identical to the uninterrupted run, points in == out, the
/// reused tiles reported.
#[test]
fn killed_ten_times_then_resumed_is_byte_identical() {
    let d = tempfile::tempdir().unwrap();
    let inputs = scene(d.path(), 250);
    let reference = d.path().join("reference");
    let (t_ref, t_first, gap) = timed_run(&reference, &inputs);
    let s_ref = summary(&reference);
    let points = s_ref["points_in"].as_u64().unwrap();
    assert!(points >= 5_000_000, "{points} points");
    let expected = outputs(&reference);

    let seed = std::env::var("TESSERA_KILL_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_261_125u64);
    let mut rng = Lcg(seed);
    let out = d.path().join("out");
    // Five kills early in a run and five later, in a seeded order.
    let mut early_kills = [
        true, true, true, true, true, false, false, false, false, false,
    ];
    for i in (1..early_kills.len()).rev() {
        let j = (rng.next_f64() * (i + 1) as f64) as usize;
        early_kills.swap(i, j.min(i));
    }
    let mut kills = Vec::new();
    for (k, &early) in early_kills.iter().enumerate() {
        // The moments are scaled by the uninterrupted run's own timeline on this machine, so
        // that they mean the same on a fast machine as on a slow one (fixed delays let a fast
        // machine finish the scene before the tenth kill). An early kill lands at a random
        // moment before the reference journaled its first cell: while inputs are read, tiled
        // again and the first cells processed. A late one lands a random 0–60 % of the
        // reference's time between two journal bursts after the run journaled its next line:
        // while cells are processed and stitched tiles written. Either is brought forward to
        // the moment the journal grows by more than it should (1 line early, 3 late), so the
        // ten kills cost at most 20 of the 250 m scene's 24 journal lines (12 cells, 12 tiles
        // written) and every kill meets a live run.
        let delay = Duration::from_secs_f64(if early {
            rng.next_f64() * t_first
        } else {
            rng.next_f64() * 0.6 * gap
        });
        let before = journal_lines(&out);
        let limit = before + if early { 1 } else { 3 };
        let mut child = run_cmd(&out, &inputs, &[]).spawn().unwrap();
        let t = Instant::now();
        let mut since: Option<Instant> = early.then_some(t);
        loop {
            if let Some(st) = child.try_wait().unwrap() {
                panic!("seed {seed}: run {k} ended ({st}) before its kill");
            }
            let lines = journal_lines(&out);
            if lines >= limit || since.is_some_and(|s| s.elapsed() >= delay) {
                break;
            }
            if since.is_none() && lines > before {
                since = Some(Instant::now());
            }
            assert!(t.elapsed() < Duration::from_secs_f64(3.0 * t_ref + 60.0));
            std::thread::sleep(Duration::from_millis(5));
        }
        child.kill().unwrap();
        let st = child.wait().unwrap();
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(st.signal(), Some(9), "seed {seed}: run {k} was not killed");
        assert!(!out.join("summary.json").exists());
        kills.push((t.elapsed().as_secs_f64(), before, journal_lines(&out)));
    }
    eprintln!(
        "seed {seed}: reference {t_ref:.2} s, first cell at {t_first:.2} s, {gap:.2} s between \
         journal bursts; kills (s after start, journal lines before, after): {kills:?}"
    );
    let o = run_cmd(&out, &inputs, &[]).output().unwrap();
    assert!(o.status.success(), "seed {seed}: {}", stderr(&o));
    let s = summary(&out);
    assert_eq!(s["points_in"].as_u64(), Some(points));
    assert_eq!(s["points_out"].as_u64(), Some(points));
    let (reused, recomputed) = (
        s["tiles_reused"].as_u64().unwrap(),
        s["tiles_recomputed"].as_u64().unwrap(),
    );
    assert_eq!(reused + recomputed, s_ref["tiles"].as_u64().unwrap());
    assert!(reused > 0, "seed {seed}: nothing was reused: {kills:?}");
    assert!(
        outputs(&out) == expected,
        "seed {seed}: the resumed run's outputs differ from the uninterrupted run's"
    );
    assert!(!out.join(".tessera-resume").exists(), "journal left");
}

/// Runs `inputs` into `out` uninterrupted, watching its journal: the run's time, when its
/// first journal line appeared and the median time between journal bursts (lines within
/// 0.2 s of each other — cells finished together by the two workers and the tiles then
/// written — are one burst), all in seconds.
fn timed_run(out: &Path, inputs: &[PathBuf]) -> (f64, f64, f64) {
    let mut child = run_cmd(out, inputs, &[]).spawn().unwrap();
    let t = Instant::now();
    let (mut lines, mut bursts) = (0, Vec::<f64>::new());
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        let now = journal_lines(out);
        if now > lines {
            let at = t.elapsed().as_secs_f64();
            if bursts.last().is_none_or(|&b| at - b > 0.2) {
                bursts.push(at);
            }
            lines = now;
        }
        assert!(
            t.elapsed() < Duration::from_secs(600),
            "reference run hangs"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(status.success(), "reference run: {status}");
    let t_run = t.elapsed().as_secs_f64();
    assert!(!bursts.is_empty(), "the run journaled nothing");
    let mut gaps: Vec<f64> = bursts.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    // A machine fast enough to journal everything in one or two bursts: the cells' time
    // spread over them.
    let gap = match gaps.len() {
        0 | 1 => (t_run - bursts[0]) / 2.0,
        n => gaps[n / 2],
    };
    (t_run, bursts[0], gap)
}

/// Kills a run of `inputs` into `out` once its journal records at least one cell.
fn kill_after_first_cell(out: &Path, inputs: &[PathBuf]) {
    let mut child = run_cmd(out, inputs, &[]).spawn().unwrap();
    let t = Instant::now();
    while journal_lines(out) == 0 {
        assert!(child.try_wait().unwrap().is_none(), "run ended early");
        assert!(t.elapsed() < Duration::from_secs(300), "no cell finished");
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
}

/// Not the same run → refused (exit 2) naming what changed; the interrupted run's journal
/// survives the refusal; `--restart` starts over and ends like an uninterrupted run.
#[test]
fn changed_input_or_setting_is_refused_and_restart_starts_over() {
    let d = tempfile::tempdir().unwrap();
    let inputs = scene(d.path(), 80);
    let reference = d.path().join("reference");
    let o = run_cmd(&reference, &inputs, &[]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let out = d.path().join("out");
    kill_after_first_cell(&out, &inputs);
    let lines = journal_lines(&out);

    let o = run_cmd(&out, &inputs, &["--set", "segment.params.k=21"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("setting segment.params.k: 20 → 21"),
        "{}",
        stderr(&o)
    );
    let o = run_cmd(&out, &inputs[..1], &[]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("is gone"), "{}", stderr(&o));
    // The same bytes, touched: modified since.
    let f = std::fs::File::options()
        .append(true)
        .open(&inputs[1])
        .unwrap();
    f.set_modified(std::time::SystemTime::now() + Duration::from_secs(5))
        .unwrap();
    drop(f);
    let o = run_cmd(&out, &inputs, &[]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("modified since"), "{}", stderr(&o));
    assert!(stderr(&o).contains("--restart"), "{}", stderr(&o));
    assert_eq!(
        journal_lines(&out),
        lines,
        "a refused run changed the journal"
    );

    let o = run_cmd(&out, &inputs, &["--restart"]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out);
    assert_eq!(s["tiles_reused"], 0);
    same_outputs(&out, &reference);
}

/// An unchanged rerun after a kill resumes: the finished cells are reused, not recomputed.
#[test]
fn same_command_resumes_and_reports_reused_tiles() {
    let d = tempfile::tempdir().unwrap();
    let inputs = scene(d.path(), 80);
    let reference = d.path().join("reference");
    let o = run_cmd(&reference, &inputs, &[]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let out = d.path().join("out");
    kill_after_first_cell(&out, &inputs);
    let o = run_cmd(&out, &inputs, &[]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out);
    assert!(s["tiles_reused"].as_u64().unwrap() >= 1, "{s}");
    assert_eq!(
        s["tiles_reused"].as_u64().unwrap() + s["tiles_recomputed"].as_u64().unwrap(),
        summary(&reference)["tiles"].as_u64().unwrap()
    );
    same_outputs(&out, &reference);
}
