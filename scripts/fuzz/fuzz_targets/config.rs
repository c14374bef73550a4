//! Configuration: a user TOML file and `--set` overrides, through the loader and every
//! section's checks.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (file, sets) = text.split_once('\u{0}').unwrap_or((text, ""));
    let p = common::file_with(file.as_bytes(), "toml");
    let overrides: Vec<String> = sets.lines().map(str::to_string).collect();
    let _ = tessera::Config::load(Some(&p), &overrides);
    let _ = tessera::Config::load(None, &[file.to_string()]);
});
