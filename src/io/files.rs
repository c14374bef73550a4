//! File-system checks every reader goes through: only regular files are opened (a FIFO or a
//! device would block a nightly run forever or stream endless bytes), and small text inputs
//! are read with a size bound.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// What a path is, in words, for error messages (`stat` follows symlinks, so a link to a
/// regular file is a regular file).
fn kind(ft: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_dir() {
        "a directory"
    } else if ft.is_fifo() {
        "a FIFO (named pipe)"
    } else if ft.is_socket() {
        "a socket"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else {
        "not a regular file"
    }
}

/// Fails unless `path` is a regular file (after following symlinks); returns its length.
/// Checked with `stat` before any `open`, because opening a FIFO for reading blocks until a
/// writer appears.
pub fn require_regular(path: &Path) -> Result<u64> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::bad_input(
            path,
            format!(
                "{} is {}, not a regular file; tessera reads only regular files",
                path.display(),
                kind(meta.file_type())
            ),
        ));
    }
    Ok(meta.len())
}

/// Opens a regular file for reading (see [`require_regular`]).
pub fn open_regular(path: &Path) -> Result<std::fs::File> {
    require_regular(path)?;
    std::fs::File::open(path).map_err(|e| Error::io(path, e))
}

/// Reads a small text file (configuration, JSON, trajectories) of at most `max_bytes`; a
/// larger file is an error naming the bound, not an allocation that grows without limit.
pub fn read_text_bounded(path: &Path, max_bytes: u64) -> Result<String> {
    let f = open_regular(path)?;
    let mut buf = Vec::new();
    f.take(max_bytes + 1)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    if buf.len() as u64 > max_bytes {
        return Err(Error::bad_input(
            path,
            format!("larger than the {max_bytes} bytes allowed for this kind of file"),
        ));
    }
    String::from_utf8(buf).map_err(|e| {
        Error::bad_input(
            path,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_fifos_and_directories_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe.las");
        // mkfifo(1) keeps `unsafe` out of this module.
        let ok = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .map(|s| s.success())
            .unwrap_or(false);
        if ok {
            let e = open_regular(&fifo).unwrap_err().to_string();
            assert!(e.contains("FIFO"), "{e}");
        }
        let e = require_regular(dir.path()).unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
    }

    #[test]
    fn bounded_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(&p, "a = 1\n").unwrap();
        assert_eq!(read_text_bounded(&p, 100).unwrap(), "a = 1\n");
        let e = read_text_bounded(&p, 3).unwrap_err().to_string();
        assert!(e.contains("larger than the 3 bytes"), "{e}");
    }
}
