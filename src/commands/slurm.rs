//! `tessera slurm DIR`: Slurm batch scripts for a region plan — a job array of its tasks and a
//! stitch job that runs once every task succeeded (`afterok`), plus `submit.sh` to submit
//! both. A task that fails is run again inside its array element (it resumes from its
//! journal); `--requeue` lets Slurm restart one whose node failed (it resumes too).

use std::path::Path;
use tessera::pipeline::task::PlanFile;
use tessera::{Config, Error};

/// Options of `tessera slurm`.
pub struct SlurmOpts {
    pub tasks: Option<usize>,
    pub partition: Option<String>,
    pub time: Option<String>,
    pub parallel: Option<usize>,
    pub submit: bool,
}

/// Attempts per array element: the first run and two resumes.
const ATTEMPTS: u32 = 3;

fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// Writes DIR/slurm/{tasks.sbatch, stitch.sbatch, submit.sh}; submits with `opts.submit`.
pub fn slurm(dir: &Path, opts: &SlurmOpts) -> anyhow::Result<()> {
    let dir = std::fs::canonicalize(dir).map_err(|e| Error::io(dir, e))?;
    let plan = PlanFile::load(&dir)?;
    let n = plan.tasks.len();
    if let Some(t) = opts.tasks {
        if t != n {
            return Err(Error::Config(format!(
                "slurm: the plan in {} has {n} tasks, not {t}; plan again with --tasks {t}",
                dir.display()
            ))
            .into());
        }
    }
    let cfg = Config::load(Some(&PlanFile::config_path(&dir)), &[])?;
    // One worker per CPU; the memory budget is the task's peak, plus room for the binary and
    // the allocator's slack, which Slurm's cgroup limit counts too.
    let cpus = match cfg.pipeline.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        t => t,
    };
    let mem_mb = cfg.pipeline.memory_budget_mb + cfg.pipeline.memory_budget_mb / 8 + 64;
    let exe = std::env::current_exe()?;
    let exe = quote(&exe.display().to_string());
    let d = quote(&dir.display().to_string());
    let sdir = dir.join("slurm");
    std::fs::create_dir_all(&sdir).map_err(|e| Error::io(&sdir, e))?;
    let log = |name: &str| sdir.join(name).display().to_string();
    let mut common = String::new();
    if let Some(p) = &opts.partition {
        common.push_str(&format!("#SBATCH --partition={p}\n"));
    }
    if let Some(t) = &opts.time {
        common.push_str(&format!("#SBATCH --time={t}\n"));
    }
    let throttle = opts.parallel.map(|p| format!("%{p}")).unwrap_or_default();
    let tasks = format!(
        "#!/bin/bash\n\
         # tessera: one array element per task of the plan in {dir}.\n\
         #SBATCH --job-name=tessera-tasks\n\
         #SBATCH --array=0-{last}{throttle}\n\
         #SBATCH --cpus-per-task={cpus}\n\
         #SBATCH --mem={mem_mb}M\n\
         #SBATCH --output={out}\n\
         #SBATCH --requeue\n\
         {common}\
         set -u\n\
         # A failed attempt is resumed from the task's journal (finished cells are kept).\n\
         for attempt in $(seq 1 {ATTEMPTS}); do\n\
         \x20 {exe} run --plan {d} --task \"$SLURM_ARRAY_TASK_ID\" && exit 0\n\
         \x20 echo \"tessera: task $SLURM_ARRAY_TASK_ID attempt $attempt failed\" >&2\n\
         done\n\
         exit 1\n",
        dir = dir.display(),
        last = n.saturating_sub(1),
        out = log("task-%a.log"),
    );
    let stitch = format!(
        "#!/bin/bash\n\
         # tessera: joins the tasks of the plan in {dir} (submitted with afterok on the array).\n\
         #SBATCH --job-name=tessera-stitch\n\
         #SBATCH --cpus-per-task=1\n\
         #SBATCH --mem={mem_mb}M\n\
         #SBATCH --output={out}\n\
         {common}\
         set -eu\n\
         exec {exe} stitch --overwrite {d}\n",
        dir = dir.display(),
        out = log("stitch.log"),
    );
    let submit = "#!/bin/bash\n\
         # Submits the task array, then the stitch job to run after every task succeeded.\n\
         set -euo pipefail\n\
         here=\"$(cd \"$(dirname \"$0\")\" && pwd)\"\n\
         tasks=$(sbatch --parsable \"$here/tasks.sbatch\")\n\
         tasks=${tasks%%;*}\n\
         stitch=$(sbatch --parsable --dependency=afterok:$tasks \"$here/stitch.sbatch\")\n\
         echo \"$tasks ${stitch%%;*}\"\n"
        .to_string();
    for (name, body) in [
        ("tasks.sbatch", tasks),
        ("stitch.sbatch", stitch),
        ("submit.sh", submit),
    ] {
        let p = sdir.join(name);
        tessera::io::write_atomic(&p, body.as_bytes())?;
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755))
            .map_err(|e| Error::io(&p, e))?;
    }
    println!(
        "{n} tasks ({cpus} CPUs, {mem_mb} MiB each) and a stitch job: {}",
        sdir.display()
    );
    if opts.submit {
        let o = std::process::Command::new("bash")
            .arg(sdir.join("submit.sh"))
            .output()
            .map_err(|e| Error::Config(format!("slurm: cannot run sbatch: {e}")))?;
        if !o.status.success() {
            return Err(Error::Config(format!(
                "slurm: submission failed: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ))
            .into());
        }
        let ids = String::from_utf8_lossy(&o.stdout);
        let mut it = ids.split_whitespace();
        println!(
            "submitted: task array {}, stitch job {}",
            it.next().unwrap_or("?"),
            it.next().unwrap_or("?")
        );
    } else {
        println!("submit with: bash {}", sdir.join("submit.sh").display());
    }
    Ok(())
}
