//! Slurm (issue 20): on a real one-node Slurm cluster (scripts/slurm_local.sh), `tessera slurm
//! DIR --submit` runs a 4-task array and the stitch job after it (afterok); the result is
//! byte-identical to one `tessera run`. The test starts the cluster when it is down (and stops
//! it afterwards); it skips, loudly, only when slurm-wlm/munge cannot be installed (exit 3).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(o: Output, what: &str) -> Output {
    assert!(
        o.status.success(),
        "{what}: {}{}",
        String::from_utf8_lossy(&o.stdout),
        stderr(&o)
    );
    o
}

fn cluster(cmd: &str) -> Output {
    Command::new("bash")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm_local.sh"))
        .arg(cmd)
        .output()
        .unwrap()
}

/// Stops the cluster when the test started it.
struct Stop(bool);
impl Drop for Stop {
    fn drop(&mut self) {
        if self.0 {
            let _ = cluster("stop");
        }
    }
}

fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_type().unwrap().is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| (n.ends_with(".laz") || n.ends_with(".tsv")) && n != "tiles.tsv")
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).unwrap();
            (n, bytes)
        })
        .collect();
    v.sort();
    v
}

#[test]
fn slurm_array_and_stitch_equal_single_run() {
    let was_up = cluster("status").status.success();
    if !was_up {
        let o = cluster("start");
        if o.status.code() == Some(3) {
            eprintln!(
                "\n\n*** SKIP: the Slurm test cannot run: slurm-wlm/munge cannot be installed here ***\n{}\n",
                stderr(&o)
            );
            return;
        }
        ok(o, "scripts/slurm_local.sh start");
    }
    let _stop = Stop(!was_up);
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("scene");
    ok(
        tessera()
            .args(["-q", "synth", "--length-m", "60", "--out"])
            .arg(&scene)
            .output()
            .unwrap(),
        "synth",
    );
    let mut inputs: Vec<PathBuf> = std::fs::read_dir(&scene)
        .unwrap()
        .flatten()
        .map(|e| std::fs::canonicalize(e.path()).unwrap())
        .filter(|p| p.extension().is_some_and(|e| e == "laz"))
        .collect();
    inputs.sort();
    let sets = ["tiling.tile_size_m=20", "tiling.buffer_m=8"];
    let mut c = tessera();
    c.args(["-q", "run"]);
    for s in sets {
        c.args(["--set", s]);
    }
    let single = d.path().join("single");
    ok(
        c.arg("--out").arg(&single).args(&inputs).output().unwrap(),
        "single run",
    );
    let plan = d.path().join("plan");
    let mut c = tessera();
    c.args(["-q", "plan", "--tasks", "4", "--out"]).arg(&plan);
    for s in sets {
        c.args(["--set", s]);
    }
    ok(c.args(&inputs).output().unwrap(), "plan");
    let o = ok(
        tessera()
            .args(["slurm", "--submit", "--time", "00:20:00"])
            .arg(&plan)
            .output()
            .unwrap(),
        "tessera slurm --submit",
    );
    let said = String::from_utf8_lossy(&o.stdout).into_owned();
    let stitch_job = said
        .split("stitch job ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .unwrap_or_else(|| panic!("no stitch job id in: {said}"))
        .to_string();
    // Wait until the stitch job has left the queue.
    let t = Instant::now();
    loop {
        let q = Command::new("squeue")
            .args(["-h", "-j", &stitch_job, "-o", "%T"])
            .output()
            .unwrap();
        let state = String::from_utf8_lossy(&q.stdout).trim().to_string();
        if state.is_empty() {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(900),
            "stitch job {stitch_job} still {state}"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    let logs = std::fs::read_dir(plan.join("slurm"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".log"))
        .map(|e| {
            format!(
                "{}:\n{}",
                e.file_name().to_string_lossy(),
                std::fs::read_to_string(e.path()).unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert!(
        plan.join("summary.json").is_file(),
        "the stitch job wrote no summary; logs:\n{logs}"
    );
    let (got, expected) = (outputs(&plan), outputs(&single));
    assert_eq!(
        got.iter().map(|x| &x.0).collect::<Vec<_>>(),
        expected.iter().map(|x| &x.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in got.iter().zip(&expected) {
        assert!(a == b, "{name} differs from the single run's");
    }
    // Four array elements ran (one log each).
    for i in 0..4 {
        assert!(
            plan.join(format!("slurm/task-{i}.log")).is_file(),
            "no log of task {i}"
        );
    }
}
