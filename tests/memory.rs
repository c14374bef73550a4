//! Memory: the pipeline on ≥ 20 M synthetic points with `--memory-budget 256` keeps its peak
//! RSS, as measured by the OS (`/usr/bin/time -v`, and VmHWM in summary.json), under 256 MiB.

use std::process::Command;

mod common;
use common::{max_rss_kb, run_summary, timed};

#[test]
fn twenty_million_points_stay_under_256_mib() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("scene");
    let out = d.path().join("out");
    let exe = env!("CARGO_BIN_EXE_tessera");
    let st = Command::new(exe)
        .args(["-q", "synth", "--length-m", "1000", "--seed", "3", "--out"])
        .arg(&scene)
        .status()
        .unwrap();
    assert!(st.success());
    let (mut cmd, timed) = timed(exe);
    let o = cmd
        .args([
            "-q",
            "run",
            "--memory-budget",
            "256",
            "--set",
            "stages.run=[\"stats\"]",
            "--out",
        ])
        .arg(&out)
        .arg(&scene)
        .output()
        .unwrap();
    let (summary, err) = run_summary(&o, &out);
    let points = summary["points_out"].as_u64().unwrap();
    assert!(points >= 20_000_000, "only {points} points");
    assert_eq!(summary["points_in"], summary["points_out"]);
    let hwm = summary["peak_rss_mb"].as_f64().unwrap();
    eprintln!(
        "{points} points, VmHWM {hwm:.1} MiB, tiles {}, split {}",
        summary["tiles"], summary["tiles_split"]
    );
    assert!(hwm > 10.0 && hwm < 256.0, "VmHWM {hwm} MiB");
    if timed {
        let kb = max_rss_kb(&err).expect("time -v output");
        eprintln!("/usr/bin/time max RSS {:.1} MiB", kb / 1024.0);
        assert!(kb / 1024.0 < 256.0, "max RSS {kb} KiB");
    }
}
