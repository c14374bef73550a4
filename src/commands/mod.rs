//! One file per command; each turns its parsed arguments into library calls and prints its
//! results. Errors go back to `main`, which alone decides the exit code.

mod demo;
mod eval;
mod info;
mod plan;
mod progress;
mod run;
mod samples;
mod slurm;
mod synth;
mod thin;
mod train;

use tessera::cli::{Cli, Command};

/// Runs the command `cli` names.
pub fn dispatch(cli: Cli) -> anyhow::Result<()> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Run {
            inputs,
            out,
            plan,
            task,
            opts,
        } => match (plan, out) {
            (Some(plan), _) => run::run_task(&plan, task, &opts, quiet),
            (None, Some(out)) => run::run(&inputs, &out, &opts, quiet),
            (None, None) => Err(tessera::Error::Config("run: --out is required".into()).into()),
        },
        Command::Stitch { dir, overwrite } => run::stitch(&dir, overwrite, quiet),
        Command::Report { dir } => {
            let c = tessera::report::html::regenerate(&dir)?;
            if !quiet {
                println!(
                    "{}: {} points in {} cells, {:.2} s",
                    dir.join(tessera::report::html::REPORT).display(),
                    c.points,
                    c.pixels,
                    c.seconds
                );
            }
            Ok(())
        }
        Command::Slurm {
            dir,
            tasks,
            partition,
            time,
            parallel,
            submit,
        } => slurm::slurm(
            &dir,
            &slurm::SlurmOpts {
                tasks,
                partition,
                time,
                parallel,
                submit,
            },
        ),
        Command::Plan {
            inputs,
            out,
            tasks,
            cfg,
        } => plan::plan(&inputs, &out, tasks, &cfg, quiet),
        Command::Synth(args) => synth::synth(args),
        Command::Demo {
            out,
            length_m,
            opts,
        } => demo::demo(&out, length_m, &opts, quiet),
        Command::Samples(args) => samples::samples(args),
        Command::Train(args) => train::train(args, quiet),
        Command::Thin {
            spacing,
            input,
            output,
        } => thin::thin(spacing, &input, &output),
        Command::Eval { what } => eval::eval(what),
        Command::Info { file } => info::info(&file),
    }
}
