//! Trajectory files: one pose per line, `time, x, y, z, qx, qy, qz, qw` (commas or white
//! space; `#` starts a comment; a first line that is not numeric is a header). Time is in
//! seconds on the recording's clock (the clock of the message stamps). Each row is the pose of
//! the trajectory frame (e.g. `base_link`) in the target frame.

use super::tf::{iso_from, TransformStamped};
use super::wire::Stamp;
use crate::error::{Error, Result};
use std::path::Path;

/// Parses a decimal number of seconds exactly into nanoseconds (f64 would lose ~0.2 µs at
/// current epoch times). Accepts an optional sign, digits, an optional fraction and an
/// optional exponent (then via f64).
fn parse_time_ns(s: &str) -> Option<i128> {
    if s.contains(['e', 'E']) {
        let v: f64 = s.parse().ok()?;
        return v.is_finite().then(|| (v * 1e9).round() as i128);
    }
    let (neg, body) = match s.strip_prefix('-') {
        Some(b) => (true, b),
        None => (false, s.strip_prefix('+').unwrap_or(s)),
    };
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    if int.is_empty() && frac.is_empty() {
        return None;
    }
    if !int.chars().all(|c| c.is_ascii_digit()) || !frac.chars().all(|c| c.is_ascii_digit()) {
        return None;
    }
    let secs: i128 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let mut ns_digits: String = frac.chars().take(9).collect();
    while ns_digits.len() < 9 {
        ns_digits.push('0');
    }
    let ns: i128 = ns_digits.parse().ok()?;
    let v = secs.checked_mul(1_000_000_000)? + ns;
    Some(if neg { -v } else { v })
}

/// Reads a trajectory file as transforms `parent → child`.
pub fn read_trajectory(path: &Path, parent: &str, child: &str) -> Result<Vec<TransformStamped>> {
    // Bounded: a trajectory of a day-long drive at 200 Hz is ~100 MB of text.
    let text = crate::io::files::read_text_bounded(path, 1 << 30)?;
    let mut out = Vec::new();
    let mut seen_data = false;
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let cols: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        let t = cols.first().and_then(|s| parse_time_ns(s));
        if t.is_none() && !seen_data {
            seen_data = true; // a header line
            continue;
        }
        seen_data = true;
        let bad = |why: String| Error::bad_input(path, format!("line {}: {why}", ln + 1));
        let first = cols.first().copied().unwrap_or(line);
        let t = t.ok_or_else(|| bad(format!("time \"{first}\" is not a number")))?;
        if cols.len() != 8 {
            return Err(bad(format!(
                "expected 8 columns (time, x, y, z, qx, qy, qz, qw), found {}",
                cols.len()
            )));
        }
        let mut v = [0.0f64; 7];
        for (k, s) in cols[1..].iter().enumerate() {
            v[k] = s
                .parse()
                .map_err(|_| bad(format!("column {} \"{s}\" is not a number", k + 2)))?;
        }
        let iso = iso_from([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]).map_err(bad)?;
        out.push(TransformStamped {
            stamp: Stamp::from_nanos(t),
            parent: parent.to_string(),
            child: child.to_string(),
            iso,
        });
    }
    if out.is_empty() {
        return Err(Error::bad_input(path, "trajectory file holds no poses"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzzing regression: a line of separators only after the header indexed an empty row.
    #[test]
    fn separator_only_lines_are_errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("t.csv");
        std::fs::write(&p, "e,time,xx,\n,\n17000s0.00000").unwrap();
        let e = read_trajectory(&p, "map", "base").unwrap_err().to_string();
        assert!(e.contains("t.csv") && e.contains("line 2"), "{e}");
    }

    #[test]
    fn times_parse_exactly() {
        assert_eq!(
            parse_time_ns("1700000000.123456789"),
            Some(1_700_000_000_123_456_789)
        );
        assert_eq!(parse_time_ns("-1.5"), Some(-1_500_000_000));
        assert_eq!(parse_time_ns("12"), Some(12_000_000_000));
        assert_eq!(parse_time_ns(".25"), Some(250_000_000));
        assert_eq!(parse_time_ns("1e3"), Some(1_000_000_000_000));
        assert_eq!(parse_time_ns("time"), None);
        assert_eq!(parse_time_ns("1.2.3"), None);
    }

    #[test]
    fn reads_rows_with_header_comments_and_either_separator() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("traj.csv");
        std::fs::write(
            &p,
            "time,x,y,z,qx,qy,qz,qw\n# comment\n10.5, 1, 2, 3, 0, 0, 0, 1\n11 4 5 6 0 0 1 0\n",
        )
        .unwrap();
        let t = read_trajectory(&p, "map", "base_link").unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].stamp.as_nanos(), 10_500_000_000);
        assert_eq!(t[1].iso.translation.vector.z, 6.0);
        assert!((t[1].iso.rotation.angle() - std::f64::consts::PI).abs() < 1e-12);
        std::fs::write(&p, "time x y\n1,2,3\n").unwrap();
        let e = read_trajectory(&p, "map", "b").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("8 columns"), "{e}");
        std::fs::write(&p, "1,0,0,0,0,0,0,0\n").unwrap();
        assert!(read_trajectory(&p, "map", "b").is_err());
    }
}
