//! Thin binary: parse → configure → run → exit code (0 ok, 1 processing error, 2 usage or
//! configuration error).

use anyhow::Context;
use clap::Parser;
use std::io::IsTerminal;
use std::process::ExitCode;
use tessera::cli::{Cli, Command, EvalCommand, SceneKind};
use tessera::{Config, Error};

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
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level)),
        )
        .with_writer(std::io::stderr)
        .with_target(false)
        .init();
    tessera::sys::tame_allocator();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let usage = e
                .downcast_ref::<Error>()
                .map(|e| e.is_usage())
                .unwrap_or(false);
            ExitCode::from(if usage { 2 } else { 1 })
        }
    }
}

/// Progress reporting: a bar on a terminal, a log line every few seconds otherwise.
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    last: std::sync::Mutex<std::time::Instant>,
    quiet: bool,
}

impl Progress {
    fn new(quiet: bool) -> Self {
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(0);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} points ({per_sec}, eta {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        Progress {
            bar,
            last: std::sync::Mutex::new(std::time::Instant::now()),
            quiet,
        }
    }
    fn update(&self, done: u64, total: u64) {
        if let Some(b) = &self.bar {
            b.set_length(total);
            b.set_position(done);
        } else if !self.quiet {
            let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
            if last.elapsed().as_secs_f64() >= 5.0 || done == total {
                *last = std::time::Instant::now();
                tracing::info!(
                    "read {done}/{total} points ({:.1} %)",
                    100.0 * done as f64 / total.max(1) as f64
                );
            }
        }
    }
    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

fn process(
    inputs: &[std::path::PathBuf],
    out: &std::path::Path,
    cfg: &Config,
    quiet: bool,
) -> anyhow::Result<()> {
    let progress = Progress::new(quiet);
    let res = tessera::pipeline::run(inputs, out, cfg, &|d, t| progress.update(d, t));
    progress.finish();
    let s = res?;
    tracing::info!(
        "{} points in, {} out, {} tiles ({} grid tiles split), {:.2} s, peak RSS {:.0} MiB (budget {} MiB); summary: {}",
        s.points_in,
        s.points_out,
        s.tiles,
        s.tiles_split,
        s.seconds.get("total").copied().unwrap_or(0.0),
        s.peak_rss_mb,
        s.memory_budget_mb,
        out.join("summary.json").display()
    );
    Ok(())
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Run { inputs, out, opts } => {
            let cfg = Config::load(opts.config.as_deref(), &opts.overrides())?;
            process(&inputs, &out, &cfg, cli.quiet)
        }
        Command::Synth {
            out,
            seed,
            length_m,
            points_per_m2,
            file_length_m,
            scene,
            houses,
            mcap,
            rings,
            columns,
        } => {
            if mcap {
                let p = tessera::synth::lidar::LidarParams {
                    scene: tessera::synth::SceneParams {
                        seed,
                        length_m,
                        ..Default::default()
                    },
                    rings,
                    columns,
                    ..Default::default()
                };
                let s = tessera::synth::drive::write_drive(&p, &out)?;
                tracing::info!(
                    "wrote {} clouds ({} returns of {} beams) to {}",
                    s.clouds,
                    s.points,
                    s.beams,
                    out.join("drive.mcap").display()
                );
                return Ok(());
            }
            if scene == SceneKind::Buildings {
                let mut p = tessera::synth::buildings::BuildingParams {
                    seed,
                    houses,
                    ..Default::default()
                };
                if let Some(d) = points_per_m2 {
                    p.points_per_m2 = d;
                }
                let s = tessera::synth::write_buildings(&p, &out)?;
                tracing::info!(
                    "wrote {} points ({houses} houses) to {}",
                    s.points,
                    out.display()
                );
                return Ok(());
            }
            let mut p = tessera::synth::SceneParams {
                seed,
                length_m,
                ..Default::default()
            };
            if let Some(d) = points_per_m2 {
                p.points_per_m2 = d;
            }
            let s = tessera::synth::write_scene(&p, &out, file_length_m)?;
            tracing::info!(
                "wrote {} points in {} files to {}",
                s.points,
                s.files,
                out.display()
            );
            Ok(())
        }
        Command::Demo {
            out,
            length_m,
            opts,
        } => {
            let scene_dir = out.join("scene");
            let p = tessera::synth::SceneParams {
                seed: 1,
                length_m,
                ..Default::default()
            };
            let s = tessera::synth::write_scene(&p, &scene_dir, 50.0).with_context(|| {
                format!("synthesising the demo scene into {}", scene_dir.display())
            })?;
            tracing::info!("demo scene: {} points in {} files", s.points, s.files);
            // Training samples as a user would draw them: the first 50 m of the drive, the
            // four surface classes of the street-level document, from the scene's truth.
            let mut overrides = opts.overrides();
            let first = scene_dir.join("scene_00000.laz");
            if !overrides.iter().any(|o| o.starts_with("label.samples")) && first.is_file() {
                let mut set =
                    tessera::label::samples::from_classified_points(&first, "gt_class", 5.0, 30)?;
                set.samples.retain(|s| [11, 64, 65, 67].contains(&s.class));
                let path = out.join("samples.json");
                set.save(&path)?;
                tracing::info!(
                    "demo: {} training samples from the first 50 m: {}",
                    set.samples.len(),
                    path.display()
                );
                overrides.push(format!("label.samples={:?}", path.display().to_string()));
            }
            // The demo's own tiles directory: an earlier demo's tiles are replaced (only the
            // files its journal lists).
            overrides.push("output.overwrite=true".into());
            let cfg = Config::load(opts.config.as_deref(), &overrides)?;
            let tiles = out.join("tiles");
            process(std::slice::from_ref(&scene_dir), &tiles, &cfg, cli.quiet)?;
            if cfg.stages.run.iter().any(|s| s == "label") {
                let e = tessera::eval::eval_labels(
                    &scene_dir,
                    &tiles,
                    &tessera::eval::LabelEvalOptions {
                        ref_field: "gt_class".into(),
                        res_field: "classification".into(),
                        classes: vec![11, 64, 65, 67, 6, 5, 69, 70],
                        map: Vec::new(),
                        precision_m: 0.001,
                        allow_unmatched: false,
                        x_range: Some((
                            tessera::synth::WORLD_OFFSET[0] + 50.0,
                            tessera::synth::WORLD_OFFSET[0] + length_m,
                        )),
                    },
                )?;
                if !cli.quiet {
                    println!(
                        "demo: labels against the scene's truth beyond the first 50 m (11 road, 64 cycle path, 65 footpath, 67 grass, 6 building, 5 tree, 69 pole, 70 vehicle):\n{}",
                        e.table()
                    );
                }
            }
            Ok(())
        }
        Command::Samples {
            from,
            input,
            field,
            classes,
            point_classes,
            block_m,
            min_points,
            out,
        } => {
            use tessera::label::samples;
            let is_json = from.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                e.eq_ignore_ascii_case("geojson") || e.eq_ignore_ascii_case("json")
            });
            let set = if is_json {
                if input.is_empty() {
                    return Err(Error::Config(
                        "samples from polygons need the point files (--input)".into(),
                    )
                    .into());
                }
                let polys = samples::read_polygons(&from)?;
                let inputs = tessera::io::input::expand_paths(&input)?;
                samples::from_polygons(&polys, &inputs, &point_classes, min_points)?
            } else {
                let mut set = samples::from_classified_points(&from, &field, block_m, min_points)?;
                if !classes.is_empty() {
                    set.samples.retain(|s| classes.contains(&s.class));
                }
                set
            };
            set.save(&out)?;
            let mut per: std::collections::BTreeMap<u8, usize> = Default::default();
            for s in &set.samples {
                *per.entry(s.class).or_default() += 1;
            }
            tracing::info!(
                "{} samples (per class: {per:?}) written to {}",
                set.samples.len(),
                out.display()
            );
            Ok(())
        }
        Command::Thin {
            spacing,
            input,
            output,
        } => {
            let s = tessera::thin::thin_file(&input, &output, spacing)?;
            tracing::info!(
                "kept {} of {} points ({:.1} %) at spacing {spacing} m: {}",
                s.kept,
                s.seen,
                100.0 * s.kept as f64 / s.seen.max(1) as f64,
                output.display()
            );
            Ok(())
        }
        Command::Eval { what } => match what {
            EvalCommand::Labels {
                reference,
                result,
                ref_field,
                res_field,
                classes,
                map,
                x_range,
                match_precision_m,
                allow_unmatched,
                json,
            } => {
                let map = map
                    .iter()
                    .map(|m| {
                        let bad = |e: String| Error::Config(format!("--map {m}: {e}"));
                        let (to, from) = m
                            .split_once('=')
                            .ok_or_else(|| bad("expected TO=FROM,...".into()))?;
                        let to = to.trim().parse::<u8>().map_err(|e| bad(e.to_string()))?;
                        let from = from
                            .split(',')
                            .map(|x| x.trim().parse::<u8>())
                            .collect::<std::result::Result<Vec<_>, _>>()
                            .map_err(|e| bad(e.to_string()))?;
                        Ok((to, from))
                    })
                    .collect::<tessera::Result<Vec<_>>>()?;
                let o = tessera::eval::LabelEvalOptions {
                    ref_field,
                    res_field,
                    classes,
                    map,
                    precision_m: match_precision_m,
                    allow_unmatched,
                    x_range: match x_range {
                        None => None,
                        Some(r) => {
                            let v: Vec<f64> = r
                                .split(',')
                                .map(|x| x.trim().parse::<f64>())
                                .collect::<std::result::Result<_, _>>()
                                .map_err(|e| Error::Config(format!("--x-range {r}: {e}")))?;
                            match v[..] {
                                [a, b] if a < b => Some((a, b)),
                                _ => {
                                    return Err(Error::Config(format!(
                                        "--x-range {r}: expected X0,X1 with X0 < X1"
                                    ))
                                    .into())
                                }
                            }
                        }
                    },
                };
                let e = tessera::eval::eval_labels(&reference, &result, &o)?;
                if json {
                    println!(
                        "{}",
                        serde_json::to_string(&e).map_err(|e| Error::Internal(e.to_string()))?
                    );
                } else {
                    println!("reference: {}", reference.display());
                    println!("result:    {}", result.display());
                    print!("{}", e.table());
                }
                Ok(())
            }
            EvalCommand::Segments {
                reference,
                result,
                ref_field,
                res_field,
                restrict,
                global_ids,
                tolerance,
                match_precision_m,
                allow_unmatched,
                json,
            } => {
                let restrict = match restrict {
                    None => None,
                    Some(r) => {
                        let (f, v) = r.split_once('=').ok_or_else(|| {
                            Error::Config(format!("--restrict {r}: expected FIELD=V1,V2,..."))
                        })?;
                        let vals = v
                            .split(',')
                            .map(|x| x.trim().parse::<u32>())
                            .collect::<std::result::Result<Vec<_>, _>>()
                            .map_err(|e| Error::Config(format!("--restrict {r}: {e}")))?;
                        Some((f.to_string(), vals))
                    }
                };
                let o = tessera::eval::SegEvalOptions {
                    ref_field,
                    res_field,
                    restrict,
                    ids_per_file: !global_ids,
                    precision_m: match_precision_m,
                    allow_unmatched,
                    tolerances: tolerance,
                };
                let e = tessera::eval::eval_segments(&reference, &result, &o)?;
                if json {
                    println!(
                        "{}",
                        serde_json::to_string(&e).map_err(|e| Error::Internal(e.to_string()))?
                    );
                } else {
                    println!("reference: {}", reference.display());
                    println!("result:    {}", result.display());
                    print!("{}", e.table());
                }
                Ok(())
            }
            EvalCommand::Ground {
                reference,
                result,
                ref_ground_class,
                result_ground_class,
                match_precision_m,
                allow_unmatched,
                json,
            } => {
                let (s, scored) = tessera::eval::eval_ground(
                    &reference,
                    &result,
                    &ref_ground_class,
                    &result_ground_class,
                    match_precision_m,
                    allow_unmatched,
                )?;
                if json {
                    println!(
                        "{}",
                        serde_json::json!({
                            "reference": reference, "result": result, "scored_points": scored,
                            "n_ground_ref": s.n_ground_ref, "n_object_ref": s.n_object_ref,
                            "type1_pct": s.type1, "type2_pct": s.type2, "total_pct": s.total,
                            "kappa_pct": s.kappa, "a": s.a, "b": s.b, "c": s.c, "d": s.d,
                        })
                    );
                } else {
                    println!(
                        "reference: {} ({} ground, {} object)",
                        reference.display(),
                        s.n_ground_ref,
                        s.n_object_ref
                    );
                    println!(
                        "result:    {} ({scored} reference points scored)",
                        result.display()
                    );
                    println!("             result ground  result object");
                    println!("ref ground   {:>13}  {:>13}", s.a, s.b);
                    println!("ref object   {:>13}  {:>13}", s.c, s.d);
                    println!(
                        "Type I  {:6.2} %   Type II {:6.2} %   total {:6.2} %   kappa {:6.2} %",
                        s.type1, s.type2, s.total, s.kappa
                    );
                }
                Ok(())
            }
        },
        Command::Info { file } => {
            if tessera::io::mcap::is_mcap(&file) {
                print!("{}", tessera::io::mcap::info(&file)?.to_text());
                return Ok(());
            }
            let f = tessera::io::input::scan_file(&file, 0)?;
            let h = &f.header;
            let b = h.bounds();
            println!("file: {}", file.display());
            println!("version: {}", h.version());
            println!(
                "point format: {} (record {} bytes, extra bytes {})",
                h.point_format().to_u8().unwrap_or(255),
                h.point_format().len(),
                h.point_format().extra_bytes
            );
            println!("compressed: {}", h.point_format().is_compressed);
            println!("points: {}", h.number_of_points());
            println!(
                "bounds: x {} .. {}, y {} .. {}, z {} .. {}",
                b.min.x, b.max.x, b.min.y, b.max.y, b.min.z, b.max.z
            );
            let t = h.transforms();
            println!(
                "scale: {} {} {}; offset: {} {} {}",
                t.x.scale, t.y.scale, t.z.scale, t.x.offset, t.y.offset, t.z.offset
            );
            for v in h.all_vlrs() {
                println!(
                    "vlr: {} {} \"{}\" ({} bytes)",
                    v.user_id,
                    v.record_id,
                    v.description,
                    v.data.len()
                );
            }
            Ok(())
        }
    }
}
