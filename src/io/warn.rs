//! Warnings said once per process.

/// Logs `message` as a warning the first time `key` is given in this process, and never
/// again: a condition of an input or of the run's outputs is met once per tile or once per
/// scan of the inputs, and the user is told once.
pub fn warn_once(key: &str, message: impl FnOnce() -> String) {
    use std::collections::HashSet;
    use std::sync::Mutex;
    static SEEN: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let first = {
        let mut seen = SEEN.lock().unwrap_or_else(|p| p.into_inner());
        seen.get_or_insert_with(HashSet::new)
            .insert(key.to_string())
    };
    if first {
        tracing::warn!("{}", message());
    }
}
