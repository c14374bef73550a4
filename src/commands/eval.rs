//! `tessera eval ground|labels|segments`: scores a result against a reference and prints a
//! table or JSON.

use serde::Serialize;
use std::path::Path;
use tessera::cli::EvalCommand;
use tessera::Error;

/// Prints one evaluation: JSON (one line), or the two inputs and the table.
fn print_report<T: Serialize>(
    json: bool,
    value: &T,
    reference: &str,
    result: &str,
    table: impl FnOnce() -> String,
) -> anyhow::Result<()> {
    if json {
        let text = serde_json::to_string(value).map_err(|e| Error::Internal(e.to_string()))?;
        println!("{text}");
    } else {
        println!("reference: {reference}");
        println!("result:    {result}");
        print!("{}", table());
    }
    Ok(())
}

/// Runs the evaluation `what` names.
pub fn eval(what: EvalCommand) -> anyhow::Result<()> {
    match what {
        EvalCommand::Labels {
            reference,
            result,
            ref_field,
            res_field,
            classes,
            map,
            x_range,
            class_map,
            exclude,
            match_precision_m,
            allow_unmatched,
            json,
        } => {
            let ref_map = class_map
                .as_deref()
                .map(tessera::label::model::ClassMap::load)
                .transpose()?;
            let mut polygons = tessera::eval::polygons::Polygons::default();
            for f in &exclude {
                polygons.extend(tessera::eval::polygons::Polygons::from_geojson(f)?);
            }
            let o = tessera::eval::LabelEvalOptions {
                ref_field,
                res_field,
                classes,
                map: map.into_iter().map(|m| (m.to, m.from)).collect(),
                precision_m: match_precision_m,
                allow_unmatched,
                x_range: x_range.map(|r| (r.0, r.1)),
                exclude: polygons,
                ref_map,
            };
            let e = tessera::eval::eval_labels(&reference, &result, &o)?;
            print_report(json, &e, &shown(&reference), &shown(&result), || e.table())
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
            let o = tessera::eval::SegEvalOptions {
                ref_field,
                res_field,
                restrict: restrict.map(|r| (r.field, r.values)),
                ids_per_file: !global_ids,
                precision_m: match_precision_m,
                allow_unmatched,
                tolerances: tolerance,
            };
            let e = tessera::eval::eval_segments(&reference, &result, &o)?;
            print_report(json, &e, &shown(&reference), &shown(&result), || e.table())
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
            let value = serde_json::json!({
                "reference": reference, "result": result, "scored_points": scored,
                "n_ground_ref": s.n_ground_ref, "n_object_ref": s.n_object_ref,
                "type1_pct": s.type1, "type2_pct": s.type2, "total_pct": s.total,
                "kappa_pct": s.kappa, "a": s.a, "b": s.b, "c": s.c, "d": s.d,
            });
            let reference_line = format!(
                "{} ({} ground, {} object)",
                reference.display(),
                s.n_ground_ref,
                s.n_object_ref
            );
            let result_line = format!("{} ({scored} reference points scored)", result.display());
            print_report(json, &value, &reference_line, &result_line, || {
                format!(
                    "             result ground  result object\n\
                     ref ground   {:>13}  {:>13}\n\
                     ref object   {:>13}  {:>13}\n\
                     Type I  {:6.2} %   Type II {:6.2} %   total {:6.2} %   kappa {:6.2} %\n",
                    s.a, s.b, s.c, s.d, s.type1, s.type2, s.total, s.kappa
                )
            })
        }
    }
}

fn shown(p: &Path) -> String {
    p.display().to_string()
}
