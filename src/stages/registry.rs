//! The registry: the one list of stages. Adding a stage is its module (declared in
//! `stages/mod.rs`) plus one line here
//! (and its `[section]` in `config/default.toml` when it has one).

use super::stage::{Attribute, Stage, StageSpec};
use crate::error::{Error, Result};

/// Every stage tessera knows, in no particular order. Adding a stage: its module plus one
/// line here.
pub const REGISTRY: &[StageSpec] = &[
    super::stats::SPEC,
    super::ground::SPEC,
    super::segment::SPEC,
    super::label::SPEC,
];

fn spec(name: &str) -> Result<&'static StageSpec> {
    REGISTRY.iter().find(|s| s.name == name).ok_or_else(|| {
        let known: Vec<&str> = REGISTRY.iter().map(|s| s.name).collect();
        Error::Config(format!(
            "stages.run: unknown stage \"{name}\" (known: {})",
            known.join(", ")
        ))
    })
}

/// The empty table a stage without a section (or whose section is absent) is given.
fn empty() -> toml::Value {
    toml::Value::Table(toml::Table::new())
}

/// The section of `spec` in `sections` (an empty table when absent).
fn section_of(spec: &StageSpec, sections: &toml::Table) -> toml::Value {
    sections.get(spec.name).cloned().unwrap_or_else(empty)
}

/// Whether `key` names the section of a registered stage.
pub fn is_stage_section(key: &str) -> bool {
    REGISTRY.iter().any(|s| s.has_section && s.name == key)
}

/// Checks every registered stage's section in `sections` (keyed by stage name), and the stage
/// list `run`: known names, each at most once, prerequisites earlier in the list.
pub fn validate_stages(run: &[String], sections: &toml::Table) -> Result<()> {
    for s in REGISTRY {
        (s.validate)(&section_of(s, sections))?;
    }
    if run.is_empty() {
        return Err(Error::Config(
            "stages.run must name at least one stage".into(),
        ));
    }
    for (i, name) in run.iter().enumerate() {
        let s = spec(name)?;
        if run[..i].contains(name) {
            return Err(Error::Config(format!("stages.run names \"{name}\" twice")));
        }
        for need in s.reads {
            let written_before = run[..i]
                .iter()
                .any(|r| spec(r).is_ok_and(|w| w.writes.contains(need)));
            if !written_before {
                return Err(Error::Config(format!(
                    "stages.run: \"{name}\" needs {} to run before it (it reads {need})",
                    writers(*need)
                )));
            }
        }
    }
    Ok(())
}

/// The registered stages writing `a`, for messages: `"ground"` or `"a" or "b"`.
fn writers(a: Attribute) -> String {
    let names: Vec<String> = REGISTRY
        .iter()
        .filter(|s| s.writes.contains(&a))
        .map(|s| format!("\"{}\"", s.name))
        .collect();
    names.join(" or ")
}

/// Builds the stages named in `run`, in order, each from its own section in `sections`.
pub fn build_stages(run: &[String], sections: &toml::Table) -> Result<Vec<Box<dyn Stage>>> {
    run.iter()
        .map(|n| {
            let s = spec(n)?;
            (s.build)(&section_of(s, sections))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    #[test]
    fn registry_names_are_unique_prerequisites_registered_and_stages_named_as_listed() {
        let cfg = Config::defaults().unwrap();
        for (i, s) in REGISTRY.iter().enumerate() {
            assert!(
                REGISTRY[..i].iter().all(|o| o.name != s.name),
                "{} registered twice",
                s.name
            );
            for need in s.reads {
                assert!(
                    REGISTRY.iter().any(|o| o.writes.contains(need)),
                    "{} reads {need}, which no registered stage writes",
                    s.name
                );
            }
            // The built stage reports the name it is registered (and configured) under, and
            // a stage with a section finds it in the defaults.
            let built = (s.build)(&section_of(s, &cfg.sections)).unwrap();
            assert_eq!(built.name(), s.name);
            assert_eq!(built.writes(), s.writes, "{}", s.name);
            assert_eq!(
                s.has_section,
                cfg.sections.contains_key(s.name),
                "{}",
                s.name
            );
        }
    }
}
