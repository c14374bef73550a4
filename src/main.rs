//! Thin binary: parse → command → exit code (0 ok, 1 processing error, 2 usage or
//! configuration error, 3 a `--keep-going` run that finished but left inputs or tiles out,
//! 4 a run that finished complete but over its memory budget).
//! Each command lives in its own file under `commands/`.

mod commands;

use clap::Parser;
use std::process::ExitCode;
use tessera::cli::Cli;
use tessera::Error;

/// Counts heap bytes per worker, so summary.json reports each stage's peak working memory.
#[global_allocator]
static ALLOC: tessera::sys::alloc::Counting = tessera::sys::alloc::Counting;

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let level = match (cli.quiet, cli.verbose) {
        (true, _) => "error",
        (false, 0) => "info",
        (false, 1) => "debug",
        _ => "trace",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                // Dependencies speak only of errors: tessera says what matters to the user
                // itself, once (the `las` crate warned about every tile's CRS record).
                .unwrap_or_else(|_| {
                    tracing_subscriber::EnvFilter::new(format!("{level},las=error,laz=error"))
                }),
        )
        .with_writer(std::io::stderr)
        .with_target(false)
        .init();
    tessera::sys::tame_allocator();
    tessera::sys::alloc::activate();
    match commands::dispatch(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", chain(&e));
            ExitCode::from(e.downcast_ref::<Error>().map_or(1, Error::exit_code))
        }
    }
}

/// The error and its causes, each cause added only when the message so far does not already
/// say it (library errors name their cause in their own message, e.g. "FILE: No such file").
fn chain(e: &anyhow::Error) -> String {
    let mut msg = String::new();
    for cause in e.chain() {
        let s = cause.to_string();
        if !msg.contains(&s) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&s);
        }
    }
    msg
}
