//! One file per command; each turns its parsed arguments into library calls and prints its
//! results. Errors go back to `main`, which alone decides the exit code.

mod demo;
mod eval;
mod info;
mod plan;
mod progress;
mod run;
mod samples;
mod synth;
mod thin;

use tessera::cli::{Cli, Command};

/// Runs the command `cli` names.
pub fn dispatch(cli: Cli) -> anyhow::Result<()> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Run { inputs, out, opts } => run::run(&inputs, &out, &opts, quiet),
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
        Command::Thin {
            spacing,
            input,
            output,
        } => thin::thin(spacing, &input, &output),
        Command::Eval { what } => eval::eval(what),
        Command::Info { file } => info::info(&file),
    }
}
