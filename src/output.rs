//! Atomic outputs: every file pgser writes appears whole or not at all.
//!
//! Data goes to a temporary file in the destination's own folder (so the final rename never
//! crosses file systems), is fsynced, and is renamed over the destination only on `commit`.
//! If the job fails or panics first, dropping the handle deletes the temporary file.

use std::fs::File;
use std::path::{Component, Path, PathBuf};

use anyhow::{Context, Result, bail};
use tempfile::NamedTempFile;

pub struct AtomicFile {
    tmp: NamedTempFile,
    dest: PathBuf,
}

impl AtomicFile {
    #[cfg_attr(feature = "mutant-direct-write", allow(unreachable_code))]
    pub fn create(dest: &Path) -> Result<Self> {
        let name = dest.file_name().with_context(|| format!("{}: output path has no file name", dest.display()))?;
        let dir = folder_of(dest);
        if !dir.is_dir() {
            bail!("{}: output folder {} does not exist", dest.display(), dir.display());
        }
        if dest.is_dir() {
            bail!("{}: output path is a folder", dest.display());
        }
        let prefix = format!(".{}.", name.to_string_lossy());
        sweep_stale(&dir, &prefix, Stale::File);
        #[cfg(feature = "mutant-direct-write")]
        return Ok(Self { tmp: mutant::direct_file(dest)?, dest: dest.to_path_buf() });
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".tmp");
        // Temporary files are private (0600); a finished output is an ordinary file that the
        // group and others may read, as `cp` or Python's `open` would leave it.
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o644));
        let tmp = builder
            .tempfile_in(&dir)
            .with_context(|| format!("{}: cannot create a temporary file in {}", dest.display(), dir.display()))?;
        // Held until this process closes the file (or dies): how `sweep_stale` tells a live
        // writer's temporary file from a killed one's.
        // SAFETY: flock on a descriptor we own; it only sets an advisory lock.
        if unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(tmp.as_file()), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            bail!("{}: cannot lock its temporary file: {}", dest.display(), std::io::Error::last_os_error());
        }
        Ok(Self { tmp, dest: dest.to_path_buf() })
    }

    /// A second handle on the temporary file, for writers that want to own theirs.
    pub fn handle(&self) -> Result<File> {
        self.tmp.as_file().try_clone().with_context(|| format!("{}: cannot reopen temporary file", self.dest.display()))
    }

    pub fn dest(&self) -> &Path {
        &self.dest
    }

    /// An unnamed scratch file beside the output (same file system, gone when dropped), for
    /// writers that must stage data before the final layout is known.
    pub fn scratch(&self) -> Result<File> {
        tempfile::tempfile_in(folder_of(&self.dest))
            .with_context(|| format!("{}: cannot create a scratch file", self.dest.display()))
    }

    /// Flush to disk and move into place.
    pub fn commit(self) -> Result<()> {
        let dest = self.dest.clone();
        self.commit_as(&dest)
    }

    /// Flush to disk and move to `path` (in the destination's folder) instead: for a file that
    /// must wait there until another is in place (`checkpoint::commit_with`).
    pub fn commit_as(self, path: &Path) -> Result<()> {
        let dest = self.dest.clone();
        self.tmp.as_file().sync_all().with_context(|| format!("{}: fsync failed", dest.display()))?;
        self.tmp
            .persist(path)
            .map_err(|e| e.error)
            .with_context(|| format!("{}: cannot move the finished file into place", path.display()))?;
        Ok(())
    }
}

/// `path` with `suffix` appended to its file name: the files that live beside a checkpoint
/// (`.resume`, `.metrics.jsonl`, `.buffer.parquet`, `.next`, `.stale`).
pub fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(suffix);
    PathBuf::from(p)
}

/// A folder output (a Minari dataset) built beside its destination and renamed into place whole:
/// the folder counterpart of [`AtomicFile`]. Dropped before `commit`, the folder is deleted; a
/// writer that dies without a destructor leaves it, locked by nobody, for the next writer of the
/// same output to sweep. The destination must not exist: a rename never replaces a folder.
pub struct AtomicDir {
    tmp: Option<tempfile::TempDir>,
    /// Where the contents are written: the staging folder `tmp`.
    staging: PathBuf,
    /// The folder opened and flocked for as long as this writer lives (see `sweep_stale`).
    _lock: File,
    dest: PathBuf,
}

impl AtomicDir {
    #[cfg_attr(feature = "mutant-direct-write", allow(unreachable_code))]
    pub fn create(dest: &Path) -> Result<Self> {
        let name = dest.file_name().with_context(|| format!("{}: output path has no file name", dest.display()))?;
        let dir = folder_of(dest);
        let prefix = format!(".{}.", name.to_string_lossy());
        sweep_stale(&dir, &prefix, Stale::Folder);
        let tmp = tempfile::Builder::new()
            .prefix(&prefix)
            .tempdir_in(&dir)
            .with_context(|| format!("{}: cannot create a folder in {}", dest.display(), dir.display()))?;
        #[cfg(feature = "mutant-direct-write")]
        return mutant::direct_folder(tmp, dest);
        let lock =
            File::open(tmp.path()).with_context(|| format!("{}: cannot open its staging folder", dest.display()))?;
        // SAFETY: flock on a descriptor we own; it only sets an advisory lock.
        if unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(&lock), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            bail!("{}: cannot lock its staging folder: {}", dest.display(), std::io::Error::last_os_error());
        }
        let staging = tmp.path().to_path_buf();
        Ok(Self { tmp: Some(tmp), staging, _lock: lock, dest: dest.to_path_buf() })
    }

    /// Where to write the output's contents.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// Moves the finished folder into place, readable like any other output (a staging folder
    /// is private, 0700).
    pub fn commit(mut self) -> Result<()> {
        #[cfg(feature = "mutant-direct-write")]
        if self.tmp.is_none() {
            return Ok(());
        }
        let tmp = self.tmp.take().expect("present until commit");
        #[cfg(unix)]
        std::fs::set_permissions(tmp.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755))
            .with_context(|| format!("{}: cannot set the permissions of its staging folder", self.dest.display()))?;
        let path = tmp.keep();
        if let Err(e) = std::fs::rename(&path, &self.dest) {
            let _ = std::fs::remove_dir_all(&path);
            bail!("{}: cannot move the finished folder into place ({e})", self.dest.display());
        }
        Ok(())
    }
}

/// The test-only mutant `mutant-direct-write` (a cargo feature, never in a build you use): every
/// output is written in place instead of beside its destination, as a naive writer would. The
/// crash and out-of-disk tests must fail against it (`make mutants`), which shows they test the
/// atomic rename rather than pass whatever the writer does.
#[cfg(feature = "mutant-direct-write")]
mod mutant {
    use super::*;

    /// The destination itself, truncated, as the "temporary" file: a failure or a kill leaves it
    /// half-written, as a direct write does.
    pub fn direct_file(dest: &Path) -> Result<NamedTempFile> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(dest)
            .with_context(|| format!("{}: cannot create it", dest.display()))?;
        let mut tmp = NamedTempFile::from_parts(file, tempfile::TempPath::try_from_path(dest)?);
        tmp.disable_cleanup(true);
        Ok(tmp)
    }

    /// The destination folder itself, created at once and never removed.
    pub fn direct_folder(staged: tempfile::TempDir, dest: &Path) -> Result<AtomicDir> {
        drop(staged);
        std::fs::create_dir(dest).with_context(|| format!("{}: cannot create it", dest.display()))?;
        let lock = File::open(dest)?;
        Ok(AtomicDir { tmp: None, staging: dest.to_path_buf(), _lock: lock, dest: dest.to_path_buf() })
    }
}

/// What a killed writer leaves: an [`AtomicFile`]'s temporary file or an [`AtomicDir`]'s folder.
#[derive(Clone, Copy, PartialEq)]
enum Stale {
    File,
    Folder,
}

/// Removes the temporaries of `prefix` in `dir` that no live process holds: files
/// `.NAME.` + 6 random characters + `.tmp`, or folders `.NAME.` + 6 random characters. They are
/// what a writer killed by SIGKILL, the OOM killer or a power cut leaves beside its output, since
/// no destructor ran to delete them. A live writer holds an exclusive flock on its temporary
/// ([`AtomicFile::create`], [`AtomicDir::create`]), so a lock we can take means its owner is gone;
/// two pgser processes writing the same output never delete each other's. Best effort: what
/// cannot be opened or removed is left as it was.
fn sweep_stale(dir: &Path, prefix: &str, kind: Stale) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let Some(rest) = name.strip_prefix(prefix) else { continue };
        let middle = match kind {
            Stale::File => rest.strip_suffix(".tmp"),
            Stale::Folder => Some(rest),
        };
        let Some(middle) = middle else { continue };
        if middle.len() != 6 || !middle.chars().all(|c| c.is_ascii_alphanumeric()) {
            continue;
        }
        // Never follow a link: only a real file or folder of ours is removed.
        let Ok(meta) = entry.path().symlink_metadata() else { continue };
        if (kind == Stale::Folder) != meta.is_dir() {
            continue;
        }
        let path = entry.path();
        let Ok(file) = File::open(&path) else { continue };
        // SAFETY: flock on a descriptor we own, released when `file` is dropped.
        let free = unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(&file), libc::LOCK_EX | libc::LOCK_NB) } == 0;
        if free {
            let _ = match kind {
                Stale::File => std::fs::remove_file(&path),
                Stale::Folder => std::fs::remove_dir_all(&path),
            };
        }
    }
}

/// Refuse to overwrite an input with the output (we read inputs through mmap while writing),
/// or to write into an input folder (a Minari dataset: the output would become part of what it
/// was made from, and change the folder's recorded sha256).
pub fn check_not_an_input(output: &Path, inputs: &[PathBuf]) -> Result<()> {
    let out = canonical_maybe_missing(output);
    for input in inputs {
        let Ok(input_path) = std::fs::canonicalize(input) else { continue };
        if input_path == out {
            bail!("{}: output would overwrite input {}", output.display(), input.display());
        }
        if input_path.is_dir() && out.starts_with(&input_path) {
            bail!("{}: output inside input folder {}: write it elsewhere", output.display(), input.display());
        }
    }
    Ok(())
}

/// Opens an input file for reading, after refusing what is not a regular file: opening a FIFO
/// blocks until something writes to it (pgser hung there, silently), a device reads forever,
/// and a folder fails later with a message that names neither. Symlinks are followed; a loop
/// is the system's one-line error.
pub fn open_input(path: &Path) -> Result<File> {
    let at = path.display();
    let meta = std::fs::metadata(path).with_context(|| format!("{at}: cannot open"))?;
    if !meta.is_file() {
        bail!("{at}: not a regular file ({}); pgser reads files", file_kind(&meta));
    }
    File::open(path).with_context(|| format!("{at}: cannot open"))
}

/// An input file's whole contents, through [`open_input`].
pub fn read_input(path: &Path) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut open_input(path)?, &mut bytes)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(bytes)
}

/// An input text file's contents, through [`open_input`].
pub fn read_input_text(path: &Path) -> Result<String> {
    String::from_utf8(read_input(path)?).with_context(|| format!("{}: not UTF-8 text", path.display()))
}

/// What kind of file system object `meta` describes, for messages.
fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    match () {
        _ if t.is_dir() => "a folder",
        _ if t.is_fifo() => "a FIFO",
        _ if t.is_socket() => "a socket",
        _ if t.is_block_device() || t.is_char_device() => "a device",
        _ => "not a regular file",
    }
}

/// The folder a file lives in; `.` for a bare file name.
pub fn folder_of(p: &Path) -> PathBuf {
    match p.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn canonical_maybe_missing(p: &Path) -> PathBuf {
    if let Ok(c) = std::fs::canonicalize(p) {
        return c;
    }
    match p.file_name() {
        Some(name) => std::fs::canonicalize(folder_of(p)).map(|d| d.join(name)).unwrap_or_else(|_| p.to_path_buf()),
        None => p.to_path_buf(),
    }
}

/// `target` as a path relative to the folder of `file` (which need not exist yet), for footers
/// that point at their inputs: the pair can then be moved or copied together. Both are made
/// absolute (symlinks resolved) first; with no common root the absolute target is returned.
pub fn relative_to_folder_of(target: &Path, file: &Path) -> Result<PathBuf> {
    let target = std::fs::canonicalize(target).with_context(|| format!("{}: cannot resolve", target.display()))?;
    let dir = folder_of(file);
    let dir = std::fs::canonicalize(&dir).with_context(|| format!("{}: cannot resolve", dir.display()))?;
    let (t, d): (Vec<_>, Vec<_>) = (target.components().collect(), dir.components().collect());
    let common = t.iter().zip(&d).take_while(|(a, b)| a == b).count();
    // Only the root in common (`/` or a Windows prefix): a relative path would just climb to it.
    if common <= 1 {
        return Ok(target);
    }
    let mut rel: PathBuf = d[common..].iter().map(|_| std::path::Component::ParentDir).collect();
    rel.extend(&t[common..]);
    Ok(rel)
}

/// The sha256 of a file, read in 1 MiB blocks (footers and checkpoints record their inputs').
pub fn sha256_file(path: &Path) -> Result<String> {
    use sha2::Digest;
    let mut hasher = sha2::Sha256::new();
    feed_file(&mut hasher, open_input(path)?, path)?;
    Ok(hex(&hasher.finalize()))
}

/// Feeds `file`'s bytes into `hasher` in 1 MiB blocks (a file may be larger than memory);
/// returns how many were read. `path` names it in errors.
pub fn feed_file(hasher: &mut sha2::Sha256, mut file: File, path: &Path) -> Result<u64> {
    use sha2::Digest;
    use std::io::Read;
    let mut buf = vec![0u8; 1 << 20];
    let mut read = 0u64;
    loop {
        let k = file.read(&mut buf).with_context(|| format!("{}: read failed", path.display()))?;
        if k == 0 {
            return Ok(read);
        }
        hasher.update(&buf[..k]);
        read += k as u64;
    }
}

/// Lower-case hex, as `sha256sum` prints digests.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// `a/b/../c` → `a/c`, without touching the file system (the outputs may not exist yet), so
/// the paths recorded in checkpoints and printed to the user stay short and stable.
pub fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    if out.as_os_str().is_empty() { PathBuf::from(".") } else { out }
}

#[cfg(test)]
mod tests {
    use std::io::Write;

    use super::*;

    /// A killed writer's temporary file is removed by the next writer of the same output; a live
    /// writer's (locked) is not, nor files that only look alike.
    #[test]
    fn the_next_writer_sweeps_what_a_killed_one_left() {
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("t.parquet");
        let dead = dir.path().join(".t.parquet.Ab3dE9.tmp");
        let other = dir.path().join(".t.parquet.stale.tmp");
        let unrelated = dir.path().join(".u.parquet.Ab3dE9.tmp");
        for p in [&dead, &other, &unrelated] {
            std::fs::write(p, b"partial").unwrap();
        }
        let live = AtomicFile::create(&dest).unwrap();
        assert!(!dead.exists(), "the killed writer's file is still there");
        assert!(other.exists() && unrelated.exists());
        let second = AtomicFile::create(&dest).unwrap();
        assert!(live.tmp.path().exists(), "a live writer's temporary file was swept");
        second.commit().unwrap();
        live.commit().unwrap();
        assert!(!dead.exists());
    }

    #[test]
    fn uncommitted_output_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("out.parquet");
        {
            let f = AtomicFile::create(&dest).unwrap();
            f.handle().unwrap().write_all(b"partial").unwrap();
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let f = AtomicFile::create(&dest).unwrap();
        f.handle().unwrap().write_all(b"whole").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&dest).unwrap(), b"whole");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn relative_paths_climb_from_the_output_folder() {
        let dir = tempfile::tempdir().unwrap();
        let d = std::fs::canonicalize(dir.path()).unwrap();
        std::fs::create_dir_all(d.join("a/b")).unwrap();
        std::fs::create_dir_all(d.join("c")).unwrap();
        std::fs::write(d.join("c/t.parquet"), b"x").unwrap();
        let t = d.join("c/t.parquet");
        assert_eq!(relative_to_folder_of(&t, &d.join("a/b/out.parquet")).unwrap(), Path::new("../../c/t.parquet"));
        assert_eq!(relative_to_folder_of(&t, &d.join("c/out.parquet")).unwrap(), Path::new("t.parquet"));
        assert_eq!(relative_to_folder_of(&t, &d.join("out.parquet")).unwrap(), Path::new("c/t.parquet"));
    }

    #[test]
    fn missing_folder_is_named() {
        let e = AtomicFile::create(Path::new("/nonexistent-dir/x.parquet")).err().unwrap();
        assert!(e.to_string().contains("does not exist"));
    }
}
