//! What a run owns on disk, and nothing more.
//!
//! - A [`WorkDir`] is a fresh directory with a unique name (`.tessera-work-<pid>-<nonce>`)
//!   created inside a location the user names (the spill directory, or the output
//!   directory). It holds a marker file locked for the run's lifetime; it is the only thing
//!   tessera ever removes recursively. The location itself, its other contents and its
//!   siblings are never touched. Work directories left by a killed run are recognised by
//!   their marker with nobody holding its lock, and removed by the next run that looks there.
//! - An [`OutputDir`] is the user's output directory, held with a lock file for the run
//!   (a second run into it refuses). A journal lists every file a run puts there, written
//!   before the file appears, so a later `--overwrite` removes exactly one run's files and a
//!   killed run's partial output is known. Files the journal does not name are never removed,
//!   and never replaced: a commit onto an existing path is an error.

use crate::error::{Error, Result};
use std::fs::{File, OpenOptions, TryLockError};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Name prefix of work directories.
pub const WORK_PREFIX: &str = ".tessera-work-";
/// Marker file inside a work directory (locked while its run lives).
pub const WORK_MARKER: &str = "TESSERA-WORK-DIR";
/// Lock file of an output directory.
pub const LOCK_FILE: &str = ".tessera.lock";
/// Journal of an output directory: the files the last run there wrote.
pub const JOURNAL: &str = ".tessera-journal";
/// The resume directory of an output directory: the journal of finished cells an
/// interrupted run is continued from (written by `pipeline::journal`; owned, kept and removed
/// by [`OutputDir`]).
pub const RESUME_DIR: &str = ".tessera-resume";
/// The run summary's file name.
pub const SUMMARY: &str = "summary.json";

const JOURNAL_HEADER: &str = "tessera-journal 1";

/// Whether `dir` is a tessera work directory (by name and marker).
pub fn is_work_dir(dir: &Path) -> bool {
    dir.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with(WORK_PREFIX))
        && dir.join(WORK_MARKER).is_file()
}

/// Whether `dir` holds a tessera run's outputs: a journal (a run wrote files there), or a
/// live run holding its lock. A lock file alone, left by a run that was refused or failed
/// before writing anything, does not count.
pub fn is_output_dir(dir: &Path) -> bool {
    dir.join(JOURNAL).is_file() || lock_is_held(dir)
}

/// A unique, marked directory a run creates and removes (see the module docs).
#[derive(Debug)]
pub struct WorkDir {
    path: PathBuf,
    /// The locked marker: held until the directory is gone.
    _marker: File,
}

impl WorkDir {
    /// Creates a fresh work directory inside `base` (created if missing; never removed).
    pub fn create(base: &Path) -> Result<WorkDir> {
        std::fs::create_dir_all(base).map_err(|e| Error::io(base, e))?;
        sweep_stale(base);
        let nonce = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        for attempt in 0u32.. {
            let path = base.join(format!(
                "{WORK_PREFIX}{}-{nonce:x}-{attempt}",
                std::process::id()
            ));
            match std::fs::create_dir(&path) {
                Ok(()) => {
                    // The marker is locked before it gets its name, so a concurrent sweep
                    // never sees an unlocked marker of a live run.
                    let tmp = path.join(".marker.tmp");
                    let marker = (|| -> std::io::Result<File> {
                        let mut f = File::create(&tmp)?;
                        f.lock()?;
                        writeln!(
                            f,
                            "tessera work directory of process {}; removed when its run ends",
                            std::process::id()
                        )?;
                        std::fs::rename(&tmp, path.join(WORK_MARKER))?;
                        Ok(f)
                    })()
                    .map_err(|e| {
                        let _ = std::fs::remove_dir_all(&path);
                        Error::io(&path, e)
                    })?;
                    return Ok(WorkDir {
                        path,
                        _marker: marker,
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < 1000 => {}
                Err(e) => return Err(Error::io(&path, e)),
            }
        }
        unreachable!("the loop returns")
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A subdirectory (created).
    pub fn subdir(&self, name: &str) -> Result<PathBuf> {
        let p = self.path.join(name);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        Ok(p)
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        // Only this run's own, uniquely named directory.
        if let Err(e) = std::fs::remove_dir_all(&self.path) {
            if e.kind() != std::io::ErrorKind::NotFound {
                tracing::warn!(
                    "could not remove the work directory {}: {e}",
                    self.path.display()
                );
            }
        }
    }
}

/// Removes work directories in `base` left by runs that no longer exist (their marker is
/// not locked). Live runs' directories and everything else are left alone.
fn sweep_stale(base: &Path) {
    let Ok(rd) = std::fs::read_dir(base) else {
        return;
    };
    for entry in rd.flatten() {
        let path = entry.path();
        let is_dir = entry.file_type().map(|t| t.is_dir()).unwrap_or(false);
        if !is_dir || !is_work_dir(&path) {
            continue;
        }
        let Ok(marker) = File::open(path.join(WORK_MARKER)) else {
            continue;
        };
        match marker.try_lock() {
            Ok(()) => {
                tracing::info!(
                    "removing {} (left by an earlier run that did not finish)",
                    path.display()
                );
                let _ = std::fs::remove_dir_all(&path);
            }
            Err(TryLockError::WouldBlock) => {}
            Err(TryLockError::Error(_)) => {}
        }
    }
}

/// What an earlier run left in an output directory.
#[derive(Debug, Default)]
struct Previous {
    /// Files it wrote (names inside the directory).
    files: Vec<String>,
    /// Size and modification time (ns) each file had when the run committed it, where recorded.
    stamps: std::collections::HashMap<String, (u64, i128)>,
    /// Whether it finished (wrote its summary).
    finished: bool,
    /// Where the list came from.
    source: &'static str,
}

/// The user's output directory, held for one run (see the module docs).
///
/// Nothing in the directory changes until the run commits its first file: an earlier run's
/// outputs that `--overwrite` replaces are removed then, not when the directory is opened, so
/// a run that fails before it has anything to write (a typo in an input path, a refused input)
/// leaves the earlier results as they were.
#[derive(Debug)]
pub struct OutputDir {
    dir: PathBuf,
    /// The journal, once the run has started writing (see [`OutputDir::commit`]).
    journal: Option<File>,
    /// What an earlier run left and `--overwrite` replaces, until the first commit.
    previous: Option<Previous>,
    /// Staging area for files before they are committed (same file system as `dir`).
    stage: WorkDir,
    /// Files this run committed (named, in order, by the journal's `file` lines: a region of
    /// 10^6 tiles is not listed in memory).
    committed: u64,
    finished: bool,
    /// A failed run keeps what it committed and its resume directory (it can be resumed):
    /// set once the resume journal names finished work.
    resumable: bool,
    /// This run started the resume directory (a failed run that is not resumable removes
    /// it; an interrupted earlier run's is never removed by a run that is refused).
    resume_created: bool,
    /// The run created the directory (a failed run then removes it if nothing else is there).
    created: bool,
    /// The locked lock file: held until the run ends. Declared last so that it is released
    /// after everything else of the run is gone.
    _lock: File,
}

/// Removes a directory `open` created, if it holds nothing but the lock file.
struct CreatedDir {
    dir: PathBuf,
    created: bool,
}

impl Drop for CreatedDir {
    fn drop(&mut self) {
        if self.created {
            remove_if_only_lock(&self.dir);
        }
    }
}

/// Removes `dir` when it holds only tessera's lock file (a run created it and failed). The
/// caller still holds the lock; a run that opened the old lock file meanwhile notices that
/// its file is no longer the directory's lock file and tries again (see `take_lock`).
fn remove_if_only_lock(dir: &Path) {
    let only_lock = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .all(|e| e.file_name().to_str() == Some(LOCK_FILE))
        })
        .unwrap_or(false);
    if only_lock {
        let _ = std::fs::remove_file(dir.join(LOCK_FILE));
        let _ = std::fs::remove_dir(dir);
    }
}

/// Opens a bookkeeping file without following a symlink (a link planted under that name must
/// not make tessera truncate or create a file elsewhere); it must be a regular file.
fn open_no_follow(path: &Path, opts: &mut OpenOptions) -> Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    let f = opts
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    let regular = f.metadata().map(|m| m.is_file()).unwrap_or(false);
    if !regular {
        return Err(Error::OutputDir {
            path: path.to_path_buf(),
            reason: "is not a regular file; tessera keeps its own bookkeeping there".into(),
            usage: false,
        });
    }
    Ok(f)
}

/// Locks `dir`'s lock file. A held lock is another live run: refused. The file locked must
/// still be the one the directory names afterwards (a failing run may remove its lock file
/// and directory), else it tries again.
fn take_lock(dir: &Path) -> Result<File> {
    use std::os::unix::fs::MetadataExt;
    let lock_path = dir.join(LOCK_FILE);
    for _ in 0..100 {
        let lock = open_no_follow(
            &lock_path,
            OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false),
        )?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(&lock_path).unwrap_or_default();
                return Err(Error::OutputDir {
                    path: dir.to_path_buf(),
                    reason: format!(
                        "another tessera run is writing into it ({}); wait for it or choose another --out",
                        holder.trim()
                    ),
                    usage: false,
                });
            }
            Err(TryLockError::Error(e)) => return Err(Error::io(&lock_path, e)),
        }
        let held = lock.metadata().map_err(|e| Error::io(&lock_path, e))?;
        match std::fs::symlink_metadata(&lock_path) {
            Ok(now) if now.ino() == held.ino() && now.dev() == held.dev() => return Ok(lock),
            _ => {
                // Removed (or replaced) between open and lock: the directory may be gone too.
                std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            }
        }
    }
    Err(Error::OutputDir {
        path: dir.to_path_buf(),
        reason: "its lock file keeps changing; is another program removing it?".into(),
        usage: false,
    })
}

/// Whether a live run holds `dir`'s lock.
pub fn lock_is_held(dir: &Path) -> bool {
    let Ok(f) = File::open(dir.join(LOCK_FILE)) else {
        return false;
    };
    matches!(f.try_lock(), Err(TryLockError::WouldBlock))
}

/// Rewrites `name` in a finished run's directory with `bytes` (atomically) and records it in
/// the run's journal, before (the name) and after (its size and time), so a later
/// `--overwrite` run still takes it for tessera's and replaces it. Used by `tessera report`.
pub fn rewrite_in_finished_run(dir: &Path, name: &str, bytes: &[u8]) -> Result<()> {
    check_name(name)?;
    if lock_is_held(dir) {
        return Err(Error::OutputDir {
            path: dir.to_path_buf(),
            reason: "a running tessera holds this directory; try again when it has finished".into(),
            usage: false,
        });
    }
    let jpath = dir.join(JOURNAL);
    let append = |line: String| -> Result<()> {
        if !jpath.exists() {
            return Ok(());
        }
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(&jpath)
            .map_err(|e| Error::io(&jpath, e))?;
        f.write_all(line.as_bytes())
            .and_then(|_| f.sync_all())
            .map_err(|e| Error::io(&jpath, e))
    };
    append(format!("file\t{name}\n"))?;
    let path = dir.join(name);
    let tmp = dir.join(format!(".{name}.tmp"));
    if let Err(e) = std::fs::write(&tmp, bytes).and_then(|_| std::fs::rename(&tmp, &path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(&path, e));
    }
    let (len, mtime) = stamp(&std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?);
    append(format!("stamp\t{len}\t{mtime}\t{name}\n"))
}

/// Size and modification time (ns since the epoch) of a file, for the journal.
fn stamp(m: &std::fs::Metadata) -> (u64, i128) {
    use std::os::unix::fs::MetadataExt;
    (
        m.len(),
        i128::from(m.mtime()) * 1_000_000_000 + i128::from(m.mtime_nsec()),
    )
}

impl OutputDir {
    /// Takes `dir` (created if missing) for a run. Refuses when another run holds it, and
    /// when an earlier run's outputs are there unless `overwrite`; those (exactly the files
    /// that run recorded) are removed when this run commits its first file.
    pub fn open(dir: &Path, overwrite: bool) -> Result<OutputDir> {
        let created = !dir.exists();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let mut lock = take_lock(dir)?;
        // From here on, leaving (also by an error below) undoes what `open` created.
        let mut guard = CreatedDir {
            dir: dir.to_path_buf(),
            created,
        };
        let _ = lock.set_len(0).and_then(|_| {
            writeln!(
                lock,
                "process {} on {}",
                std::process::id(),
                hostname().unwrap_or_else(|| "this host".into())
            )
        });
        let prev = previous_run(dir)?;
        if let Some(prev) = &prev {
            // An interrupted run that kept a resume journal: whether this run continues it
            // is decided once the inputs are known (`pipeline::journal::start`).
            let resumable = !prev.finished && dir.join(RESUME_DIR).join("run.json").is_file();
            if !overwrite && !resumable {
                let what = if prev.finished {
                    "the outputs of an earlier run"
                } else {
                    "the partial outputs of an earlier run that did not finish"
                };
                return Err(Error::OutputDir {
                    path: dir.to_path_buf(),
                    reason: format!(
                        "holds {what} ({} files, listed in its {}); pass --overwrite to replace them (only those files are removed), or choose another --out",
                        prev.files.len(),
                        prev.source
                    ),
                    usage: true,
                });
            }
            // Refuse now, before any work, when a recorded file was changed since.
            check_unchanged(dir, prev)?;
        }
        // Staging first: it sweeps work directories of killed runs.
        let stage = WorkDir::create(dir)?;
        let foreign = foreign_entries(dir);
        if foreign > 0 {
            tracing::info!(
                "{}: {foreign} entries not written by tessera are left untouched",
                dir.display()
            );
        }
        guard.created = false;
        Ok(OutputDir {
            dir: dir.to_path_buf(),
            created,
            journal: None,
            previous: prev,
            stage,
            committed: 0,
            finished: false,
            resumable: false,
            resume_created: false,
            _lock: lock,
        })
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Where files are written before [`OutputDir::commit`] moves them in (private to this
    /// run, on the output's file system, removed with the run).
    pub fn stage(&self) -> &Path {
        self.stage.path()
    }

    /// Before the first commit: removes what `--overwrite` replaces and starts this run's
    /// journal (written whole under a temporary name, then renamed, so a journal is never
    /// found half-written).
    fn start_writing(&mut self) -> Result<&mut File> {
        if self.journal.is_none() {
            if let Some(prev) = self.previous.take() {
                check_unchanged(&self.dir, &prev)?;
                remove_previous(&self.dir, &prev)?;
            }
            let jpath = self.dir.join(JOURNAL);
            let tmp = self.stage.path().join("journal.tmp");
            let mut journal = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
            writeln!(
                journal,
                "{JOURNAL_HEADER}\tprocess {}\tstarted {}",
                std::process::id(),
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map(|d| d.as_secs())
                    .unwrap_or(0)
            )
            .and_then(|_| journal.sync_all())
            .map_err(|e| Error::io(&tmp, e))?;
            std::fs::rename(&tmp, &jpath).map_err(|e| Error::io(&jpath, e))?;
            self.journal = Some(journal);
        }
        match self.journal.as_mut() {
            Some(j) => Ok(j),
            None => Err(Error::Internal("journal not started".into())),
        }
    }

    /// Moves staged files into the directory under `name`s: each is recorded in the journal
    /// first, and an existing file of that name is never replaced.
    pub fn commit(&mut self, files: &[(PathBuf, String)]) -> Result<()> {
        let jpath = self.dir.join(JOURNAL);
        for (staged, name) in files {
            check_name(name)?;
            let target = self.dir.join(name);
            let exists = |t: &Path| std::fs::symlink_metadata(t).is_ok();
            let dir = self.dir.clone();
            let clash = || Error::OutputDir {
                path: dir.clone(),
                reason: format!(
                    "{name} already exists and was not written by this run; refusing to replace it"
                ),
                usage: false,
            };
            // First what `--overwrite` replaces goes (the earlier run's tiles may have the
            // names this run writes).
            let journal = self.start_writing()?;
            if exists(&target) {
                return Err(clash());
            }
            writeln!(journal, "file\t{name}").map_err(|e| Error::io(&jpath, e))?;
            self.committed += 1;
            // A hard link fails when the name exists (created since the check above), where a
            // rename would silently replace it; file systems without hard links get the rename.
            match std::fs::hard_link(staged, &target) {
                Ok(()) => {
                    let _ = std::fs::remove_file(staged);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    // Recorded, not created: the rollback finds no file of that name that is
                    // this run's (the clash is someone else's file, and it stays).
                    self.committed -= 1;
                    let journal = self.start_writing()?;
                    writeln!(journal, "unfile\t{name}").map_err(|e| Error::io(&jpath, e))?;
                    return Err(clash());
                }
                Err(_) => std::fs::rename(staged, &target).map_err(|e| Error::io(&target, e))?,
            }
            let (len, mtime) = std::fs::metadata(&target)
                .map(|m| stamp(&m))
                .map_err(|e| Error::io(&target, e))?;
            let journal = self.start_writing()?;
            writeln!(journal, "stamp\t{len}\t{mtime}\t{name}").map_err(|e| Error::io(&jpath, e))?;
        }
        Ok(())
    }

    /// Whether an earlier run finished here (its outputs are complete).
    pub fn previous_finished(&self) -> bool {
        self.previous.as_ref().is_some_and(|p| p.finished)
    }

    /// Continues the interrupted earlier run (a resume): the files it committed that `keep`
    /// names become this run's; the others (tiles of work the journal does not record as
    /// finished) are removed now and written again.
    pub fn adopt_previous(&mut self, keep: &std::collections::HashSet<String>) -> Result<()> {
        self.resumable = true;
        // An interrupted run that had not committed a file yet left nothing to adopt.
        let Some(prev) = self.previous.take() else {
            return Ok(());
        };
        let jpath = self.dir.join(JOURNAL);
        let mut journal = open_no_follow(&jpath, OpenOptions::new().append(true))?;
        writeln!(journal, "resumed\tprocess {}", std::process::id())
            .map_err(|e| Error::io(&jpath, e))?;
        for name in &prev.files {
            if keep.contains(name) {
                continue;
            }
            let p = self.dir.join(name);
            match std::fs::symlink_metadata(&p) {
                Ok(m) if m.is_file() => std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?,
                _ => {}
            }
        }
        self.journal = Some(journal);
        Ok(())
    }

    /// From now on a failure keeps the committed files and the resume directory: the run
    /// has finished work a rerun continues from.
    pub fn set_resumable(&mut self) {
        self.resumable = true;
    }

    /// Starts a fresh resume directory for this run (an earlier run's is removed first) and
    /// returns its path; its `parts` subdirectory is created.
    pub fn fresh_resume_dir(&mut self) -> Result<PathBuf> {
        let dir = self.dir.join(RESUME_DIR);
        remove_resume_dir(&dir)?;
        self.resume_created = true;
        let parts = dir.join("parts");
        std::fs::create_dir_all(&parts).map_err(|e| Error::io(&parts, e))?;
        Ok(dir)
    }

    /// Removes the resume directory (the run finished).
    fn clear_resume_dir(&self) -> Result<()> {
        remove_resume_dir(&self.dir.join(RESUME_DIR))
    }

    /// Writes `bytes` to the staging directory and commits them under `name` (recorded in
    /// the journal like a tile, so `--overwrite` replaces it).
    pub fn commit_bytes(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        let staged = self.stage().join(name);
        std::fs::write(&staged, bytes).map_err(|e| Error::io(&staged, e))?;
        self.commit(&[(staged, name.to_string())])
    }

    /// Files committed so far.
    pub fn committed(&self) -> u64 {
        self.committed
    }

    /// Writes the run summary (the last file) and marks the run finished; the resume
    /// directory goes (nothing is left to resume).
    pub fn finish(mut self, summary: &[u8]) -> Result<()> {
        self.write_summary(summary)?;
        if let Err(e) = self.clear_resume_dir() {
            tracing::warn!("{e}");
        }
        Ok(())
    }

    fn write_summary(&mut self, summary: &[u8]) -> Result<()> {
        let staged = self.stage().join(SUMMARY);
        std::fs::write(&staged, summary).map_err(|e| Error::io(&staged, e))?;
        self.commit(&[(staged, SUMMARY.to_string())])?;
        let jpath = self.dir.join(JOURNAL);
        let journal = self.start_writing()?;
        writeln!(journal, "done")
            .and_then(|_| journal.sync_all())
            .map_err(|e| Error::io(&jpath, e))?;
        self.finished = true;
        Ok(())
    }
}

impl OutputDir {
    /// Like [`OutputDir::finish`], but the resume directory stays: a task of a distributed
    /// run leaves its journal (deferred tiles, border summaries) for `tessera stitch`.
    pub fn finish_keeping_journal(mut self, summary: &[u8]) -> Result<()> {
        self.write_summary(summary)
    }

    /// Adds existing files (another run's, e.g. a task's tiles) under `name`s by hard link
    /// (a copy across file systems); the sources stay. Recorded like [`OutputDir::commit`].
    pub fn link(&mut self, files: &[(PathBuf, String)]) -> Result<()> {
        for (src, name) in files {
            let staged = self.stage().join(name);
            if std::fs::hard_link(src, &staged).is_err() {
                std::fs::copy(src, &staged).map_err(|e| Error::io(src, e))?;
            }
            self.commit(&[(staged, name.clone())])?;
        }
        Ok(())
    }
}

/// Removes what a finished run left in `dir` (a task directory once `tessera stitch` has
/// finished): the files its journal names, its resume directory, its bookkeeping, and the
/// directory when nothing else is in it.
pub fn remove_run_dir(dir: &Path) -> Result<()> {
    if let Some(prev) = previous_run(dir)? {
        for name in &prev.files {
            let p = dir.join(name);
            if std::fs::symlink_metadata(&p).is_ok_and(|m| m.is_file()) {
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
    }
    remove_resume_dir(&dir.join(RESUME_DIR))?;
    for f in [JOURNAL, LOCK_FILE] {
        let _ = std::fs::remove_file(dir.join(f));
    }
    let _ = std::fs::remove_dir(dir);
    Ok(())
}

impl OutputDir {
    /// Removes the files this run committed, read back from its journal (the `file` lines
    /// after the run's header; `unfile` takes back a name that was not created).
    fn remove_committed(&self) {
        use std::io::BufRead;
        let Ok(f) = File::open(self.dir.join(JOURNAL)) else {
            return;
        };
        let mut names: Vec<String> = Vec::new();
        for line in std::io::BufReader::new(f)
            .lines()
            .map_while(std::result::Result::ok)
        {
            if let Some(name) = line.strip_prefix("file\t") {
                names.push(name.to_string());
            } else if let Some(name) = line.strip_prefix("unfile\t") {
                if let Some(i) = names.iter().rposition(|n| n == name) {
                    names.remove(i);
                }
            }
        }
        for name in names.iter().rev() {
            if check_name(name).is_ok() {
                let _ = std::fs::remove_file(self.dir.join(name));
            }
        }
    }
}

impl Drop for OutputDir {
    /// A run that fails takes its partial outputs with it: the directory is left as the run
    /// found it (less what `--overwrite` removed). A killed run cannot do this; its journal
    /// lists what it left.
    fn drop(&mut self) {
        if self.finished {
            return;
        }
        if self.resumable {
            tracing::warn!(
                "{}: the run did not finish; what it finished is kept — run the same command again to resume it (or pass --restart to start over)",
                self.dir.display()
            );
            return;
        }
        if self.resume_created {
            let _ = remove_resume_dir(&self.dir.join(RESUME_DIR));
        }
        if self.committed > 0 {
            self.remove_committed();
        }
        if let Some(j) = &self.journal {
            if j.set_len(0).is_ok() {
                let _ = std::fs::remove_file(self.dir.join(JOURNAL));
            }
        }
        if self.created {
            // The staging directory goes first (fields drop after this), so look past it.
            let stage = self.stage.path().to_path_buf();
            let _ = std::fs::remove_dir_all(&stage);
            remove_if_only_lock(&self.dir);
        }
    }
}

/// Removes a resume directory: its known files, the parts directory's regular files, then the
/// directories. Anything else found there (not tessera's) stays, with a warning.
fn remove_resume_dir(dir: &Path) -> Result<()> {
    if std::fs::symlink_metadata(dir).is_err() {
        return Ok(());
    }
    let parts = dir.join("parts");
    if let Ok(rd) = std::fs::read_dir(&parts) {
        for e in rd.flatten() {
            if e.file_type().map(|t| t.is_file()).unwrap_or(false) {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        let _ = std::fs::remove_dir(&parts);
    }
    // run.json, the log, and a temporary run.json a crash left.
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let ours = name == "run.json"
                || name == "log"
                || (name.starts_with(".run.json.") && name.ends_with(".tmp"));
            if ours && e.file_type().map(|t| t.is_file()).unwrap_or(false) {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
    }
    if let Err(e) = std::fs::remove_dir(dir) {
        tracing::warn!("{} was not removed: {e}", dir.display());
    }
    Ok(())
}

/// A journal entry must name a plain file inside the directory.
fn check_name(name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.contains('\0')
        && !name.starts_with(".tessera");
    if ok {
        Ok(())
    } else {
        Err(Error::Internal(format!("bad output file name {name:?}")))
    }
}

/// Reads what an earlier run left: its journal, or (outputs of tessera versions before the
/// journal) the tile list of its summary. `None` when there is nothing.
fn previous_run(dir: &Path) -> Result<Option<Previous>> {
    let jpath = dir.join(JOURNAL);
    match std::fs::read_to_string(&jpath) {
        // An empty journal: a run of an earlier version killed before it wrote anything.
        Ok(text) if text.is_empty() && !dir.join(SUMMARY).exists() => Ok(None),
        Ok(text) => {
            let mut lines = text.lines();
            if lines.next().map(|l| l.split('\t').next()) != Some(Some(JOURNAL_HEADER)) {
                return Err(Error::OutputDir {
                    path: dir.to_path_buf(),
                    reason: format!(
                        "{JOURNAL} is not a tessera journal; refusing to guess what to remove"
                    ),
                    usage: false,
                });
            }
            let mut p = Previous {
                source: "journal",
                ..Default::default()
            };
            for l in lines {
                if let Some(name) = l.strip_prefix("file\t") {
                    if check_name(name).is_ok() {
                        p.files.push(name.to_string());
                    }
                } else if let Some(name) = l.strip_prefix("unfile\t") {
                    if let Some(i) = p.files.iter().rposition(|n| n == name) {
                        p.files.remove(i);
                    }
                } else if let Some(rest) = l.strip_prefix("stamp\t") {
                    let mut it = rest.splitn(3, '\t');
                    if let (Some(len), Some(mtime), Some(name)) = (it.next(), it.next(), it.next())
                    {
                        if let (Ok(len), Ok(mtime)) = (len.parse(), mtime.parse()) {
                            p.stamps.insert(name.to_string(), (len, mtime));
                        }
                    }
                } else if l == "done" {
                    p.finished = true;
                }
            }
            let summary = dir.join(SUMMARY).exists();
            if p.files.is_empty() && !summary {
                return Ok(None);
            }
            if summary && !p.files.iter().any(|f| f == SUMMARY) {
                // A summary the journal does not list: not this journal's run.
                return Err(Error::OutputDir {
                    path: dir.to_path_buf(),
                    reason: format!("{SUMMARY} is not listed in {JOURNAL}; refusing to guess which files are tessera's"),
                    usage: false,
                });
            }
            Ok(Some(p))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let spath = dir.join(SUMMARY);
            let text = match std::fs::read_to_string(&spath) {
                Ok(t) => t,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
                Err(e) => return Err(Error::io(&spath, e)),
            };
            let files = summary_files(dir, &text).ok_or_else(|| Error::OutputDir {
                path: dir.to_path_buf(),
                reason: format!("{SUMMARY} is not a tessera run summary; refusing to touch it"),
                usage: false,
            })?;
            Ok(Some(Previous {
                files,
                finished: true,
                source: "summary.json",
                ..Default::default()
            }))
        }
        Err(e) => Err(Error::io(&jpath, e)),
    }
}

/// Calls `f` with every tile a run summary names: the lines of its tile table when it has one
/// (read one at a time), else its `tile_list` (summaries of small runs, and of older versions).
pub fn for_each_tile(
    dir: &Path,
    summary: &serde_json::Value,
    mut f: impl FnMut(&serde_json::Value) -> Result<()>,
) -> Result<()> {
    use std::io::BufRead;
    let table = summary
        .get("tile_table")
        .and_then(serde_json::Value::as_str);
    let Some(name) = table else {
        for t in summary
            .get("tile_list")
            .and_then(serde_json::Value::as_array)
            .into_iter()
            .flatten()
        {
            f(t)?;
        }
        return Ok(());
    };
    // A summary is input: only a plain file name inside the directory.
    if name.contains('/') || name.starts_with('.') || name.is_empty() {
        return Err(Error::OutputDir {
            path: dir.to_path_buf(),
            reason: format!("summary.json names a tile table outside the directory: {name}"),
            usage: false,
        });
    }
    let path = dir.join(name);
    let file = std::fs::File::open(&path).map_err(|e| Error::io(&path, e))?;
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| Error::io(&path, e))?;
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(&line).map_err(|e| Error::OutputDir {
            path: path.clone(),
            reason: format!("line {}: not a tile record: {e}", i + 1),
            usage: false,
        })?;
        f(&v)?;
    }
    Ok(())
}

/// The files a summary of a journal-less run names: its tiles (from its tile table when it
/// has one), their segment tables, the tile table, itself.
fn summary_files(dir: &Path, text: &str) -> Option<Vec<String>> {
    let v: serde_json::Value = serde_json::from_str(text).ok()?;
    if v.get("tile_table").is_none() {
        v.get("tile_list")?.as_array()?;
    }
    let mut files = Vec::new();
    let mut complete = true;
    for_each_tile(dir, &v, |t| {
        match (
            t.get("file").and_then(serde_json::Value::as_str),
            t.get("name").and_then(serde_json::Value::as_str),
        ) {
            (Some(file), Some(name)) => {
                files.push(file.to_string());
                files.push(format!("{name}.segments.tsv"));
            }
            _ => complete = false,
        }
        Ok(())
    })
    .ok()?;
    if !complete {
        return None;
    }
    if let Some(t) = v.get("tile_table").and_then(serde_json::Value::as_str) {
        files.push(t.to_string());
    }
    files.push(SUMMARY.to_string());
    files.retain(|f| check_name(f).is_ok());
    Some(files)
}

/// Refuses to replace an earlier run's file that was changed after that run wrote it (e.g. a
/// tile edited and saved in place): it is the user's now. Files without a recorded stamp
/// (older journals) are not checked.
fn check_unchanged(dir: &Path, prev: &Previous) -> Result<()> {
    for name in &prev.files {
        let (Some(&recorded), Ok(m)) = (prev.stamps.get(name), std::fs::metadata(dir.join(name)))
        else {
            continue;
        };
        if stamp(&m) != recorded {
            return Err(Error::OutputDir {
                path: dir.to_path_buf(),
                reason: format!(
                    "{name} was written by an earlier run but changed since (size or time differs); it is not replaced — move it away first, or choose another --out"
                ),
                usage: false,
            });
        }
    }
    Ok(())
}

/// Removes an earlier run's files: the summary first (so no summary ever describes files that
/// are gone), then the rest, then its journal. Only regular files named by the record;
/// missing ones are fine (an interrupted `--overwrite` is simply repeated).
fn remove_previous(dir: &Path, prev: &Previous) -> Result<()> {
    let order = std::iter::once(SUMMARY).chain(
        prev.files
            .iter()
            .map(|s| s.as_str())
            .filter(|f| *f != SUMMARY),
    );
    let mut removed = 0usize;
    for name in order {
        if name == SUMMARY && !prev.files.iter().any(|f| f == SUMMARY) {
            continue;
        }
        let p = dir.join(name);
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.is_file() => {
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
                removed += 1;
            }
            Ok(_) => tracing::warn!(
                "{} is not a regular file; left in place although the earlier run recorded it",
                p.display()
            ),
            Err(_) => {}
        }
    }
    tracing::info!(
        "--overwrite: removed {removed} files of the earlier run in {}",
        dir.display()
    );
    Ok(())
}

/// Entries of `dir` that are not tessera's own bookkeeping.
fn foreign_entries(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .filter(|e| !e.file_name().to_string_lossy().starts_with(".tessera"))
                .count()
        })
        .unwrap_or(0)
}

fn hostname() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage_file(out: &OutputDir, name: &str, body: &str) -> (PathBuf, String) {
        let p = out.stage().join(name);
        std::fs::write(&p, body).unwrap();
        (p, name.to_string())
    }

    #[test]
    fn work_dir_is_unique_and_leaves_its_base_alone() {
        let base = tempfile::tempdir().unwrap();
        std::fs::write(base.path().join("user.txt"), "mine").unwrap();
        let a = WorkDir::create(base.path()).unwrap();
        let b = WorkDir::create(base.path()).unwrap();
        assert_ne!(a.path(), b.path());
        std::fs::write(a.path().join("spill"), "x").unwrap();
        // A live run's directory survives another run's sweep.
        sweep_stale(base.path());
        assert!(a.path().is_dir() && b.path().is_dir());
        drop(a);
        drop(b);
        let left: Vec<_> = std::fs::read_dir(base.path()).unwrap().flatten().collect();
        assert_eq!(left.len(), 1);
        assert_eq!(
            std::fs::read_to_string(base.path().join("user.txt")).unwrap(),
            "mine"
        );
    }

    #[test]
    fn stale_work_dirs_are_swept_but_look_alikes_are_not() {
        let base = tempfile::tempdir().unwrap();
        let stale = base.path().join(format!("{WORK_PREFIX}1-2-3"));
        std::fs::create_dir(&stale).unwrap();
        std::fs::write(stale.join(WORK_MARKER), "").unwrap();
        // Same name, no marker: not ours.
        let look = base.path().join(format!("{WORK_PREFIX}9-9-9"));
        std::fs::create_dir(&look).unwrap();
        std::fs::write(look.join("data"), "keep").unwrap();
        let w = WorkDir::create(base.path()).unwrap();
        assert!(!stale.exists());
        assert!(look.join("data").is_file());
        drop(w);
    }

    #[test]
    fn second_run_refuses_and_overwrite_removes_only_recorded_files() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("notes.txt"), "user").unwrap();
        let mut out = OutputDir::open(d.path(), false).unwrap();
        let e = OutputDir::open(d.path(), true).unwrap_err().to_string();
        assert!(e.contains("another tessera run"), "{e}");
        let f = stage_file(&out, "t1.laz", "tile");
        out.commit(&[f]).unwrap();
        out.finish(b"{}").unwrap();
        // Finished run: refused without overwrite.
        let e = OutputDir::open(d.path(), false).unwrap_err();
        assert!(e.to_string().contains("--overwrite"), "{e}");
        assert!(e.is_usage());
        // Overwrite: nothing changes until the run commits its first file.
        let out = OutputDir::open(d.path(), true).unwrap();
        assert!(d.path().join("t1.laz").is_file() && d.path().join(SUMMARY).is_file());
        drop(out);
        assert!(d.path().join("t1.laz").is_file() && d.path().join(SUMMARY).is_file());
        let mut out = OutputDir::open(d.path(), true).unwrap();
        let f = stage_file(&out, "t2.laz", "tile");
        out.commit(&[f]).unwrap();
        assert!(!d.path().join("t1.laz").exists());
        assert!(!d.path().join(SUMMARY).exists());
        assert!(d.path().join("notes.txt").is_file());
        // Never replaces a file it did not write.
        let f = stage_file(&out, "notes.txt", "tile");
        assert!(out.commit(&[f]).is_err());
        assert_eq!(
            std::fs::read_to_string(d.path().join("notes.txt")).unwrap(),
            "user"
        );
    }

    #[test]
    fn failed_run_takes_its_partial_outputs_with_it() {
        let d = tempfile::tempdir().unwrap();
        let mut out = OutputDir::open(d.path(), false).unwrap();
        let f = stage_file(&out, "t1.laz", "tile");
        out.commit(&[f]).unwrap();
        drop(out);
        let names: Vec<String> = std::fs::read_dir(d.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec![LOCK_FILE.to_string()]);
        // And the directory is free again.
        drop(OutputDir::open(d.path(), false).unwrap());
        // A directory the failed run created is removed with it.
        let fresh = d.path().join("new/out");
        drop(OutputDir::open(&fresh, false).unwrap());
        assert!(!fresh.exists());
        assert!(d.path().join("new").is_dir());
    }

    #[test]
    fn foreign_summary_is_never_touched() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join(SUMMARY), "not ours").unwrap();
        let e = OutputDir::open(d.path(), true).unwrap_err().to_string();
        assert!(e.contains("not a tessera run summary"), "{e}");
        assert_eq!(
            std::fs::read_to_string(d.path().join(SUMMARY)).unwrap(),
            "not ours"
        );
    }
}
