//! Where pgser finds the files it reads besides its inputs: the gymnasium-robotics model assets
//! (`PGSER_ASSETS`) and numpy's ziggurat tables (`PGSER_ZIGGURAT`).
//!
//! In order: the environment variable; then the wheel's layout beside the running executable
//! (`pgser/bin/pgser` reads `pgser/assets/` and `pgser/data/numpy_ziggurat.bin`), so that an
//! installed wheel reads nothing of the clone it was built in; then the clone's `.deps/` that
//! `make deps` fills, baked in by build.rs, so a developer's `target/release` binaries need no
//! variable. The Python module cannot use the second (its executable is python): `pgser/__init__.py`
//! sets the variables to the package's own copies when they are there.

use std::path::{Path, PathBuf};

/// `$var` if set and not empty, else `packaged` (a path relative to the folder above the
/// executable's) when it exists there, else `baked`.
pub fn data_path(var: &str, packaged: &str, baked: &str) -> PathBuf {
    if let Some(p) = std::env::var_os(var).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().ok();
    match exe.as_deref().and_then(|e| beside(e, packaged)) {
        Some(p) => p,
        None => PathBuf::from(baked),
    }
}

/// `pgser/REL` for an executable in the wheel's `pgser/bin/`, when it exists. Only that layout:
/// a binary copied to `/usr/local/bin` must not take `/usr/local/assets` for its models.
fn beside(exe: &Path, rel: &str) -> Option<PathBuf> {
    let bin = exe.parent()?;
    let package = bin.parent()?;
    if bin.file_name()? != "bin" || package.file_name()? != "pgser" {
        return None;
    }
    let p = package.join(rel);
    p.exists().then_some(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wheel_layout_is_found_beside_the_executable() {
        let dir = tempfile::tempdir().unwrap();
        let exe = dir.path().join("pgser/bin/pgser");
        std::fs::create_dir_all(dir.path().join("pgser/assets")).unwrap();
        std::fs::create_dir_all(exe.parent().unwrap()).unwrap();
        assert_eq!(beside(&exe, "assets"), Some(dir.path().join("pgser/assets")));
        assert_eq!(beside(&exe, "data/numpy_ziggurat.bin"), None, "absent: the baked path is used");
        std::fs::create_dir_all(dir.path().join("usr/assets")).unwrap();
        assert_eq!(beside(&dir.path().join("usr/bin/pgser-etl"), "assets"), None, "not the wheel's layout");
    }
}
