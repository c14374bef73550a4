// Shared by the file-based targets: the input written to a per-process file in /dev/shm
// (tessera's readers take paths, as users give them).
use std::path::PathBuf;

pub fn file_with(data: &[u8], ext: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("tessera-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let p = dir.join(format!("input.{ext}"));
    std::fs::write(&p, data).expect("write fuzz input");
    p
}
