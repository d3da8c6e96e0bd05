//! A results folder, as KISS-ICP keeps them: each run writes into `PARENT/<UTC time>/`, and
//! `PARENT/latest` points at the newest.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// A results folder that could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    /// The folder or the `latest` link could not be made.
    #[error("making the results folder {path} failed")]
    Io {
        /// What was being made.
        path: PathBuf,
        /// Why not.
        #[source]
        source: std::io::Error,
    },
    /// The parent named is something other than a folder.
    #[error("{0}: not a folder (--results names the folder that keeps the runs)")]
    NotAFolder(PathBuf),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ResultsError + '_ {
    move |source| ResultsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// `Ok` unless `parent` exists and is not a folder: a check before a run writes anything else.
pub fn check_parent(parent: &Path) -> Result<(), ResultsError> {
    if parent.exists() && !parent.is_dir() {
        return Err(ResultsError::NotAFolder(parent.to_path_buf()));
    }
    Ok(())
}

/// Makes `parent/<YYYY-MM-DD_HH-MM-SS>` (UTC; `-2`, `-3`, ... appended when two runs start in
/// the same second), points `parent/latest` at it, and returns it.
pub fn create(parent: &Path) -> Result<PathBuf, ResultsError> {
    check_parent(parent)?;
    std::fs::create_dir_all(parent).map_err(io(parent))?;
    let stamp = humantime::format_rfc3339_seconds(SystemTime::now())
        .to_string()
        .trim_end_matches('Z')
        .replace('T', "_")
        .replace(':', "-");
    let mut dir = parent.join(&stamp);
    let mut n = 1;
    loop {
        match std::fs::create_dir(&dir) {
            Ok(()) => break,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                n += 1;
                dir = parent.join(format!("{stamp}-{n}"));
            }
            Err(e) => return Err(io(&dir)(e)),
        }
    }
    let latest = parent.join("latest");
    let name = dir.file_name().unwrap_or_default();
    let staged = parent.join(".latest.tmp");
    let _ = std::fs::remove_file(&staged);
    std::os::unix::fs::symlink(name, &staged).map_err(io(&staged))?;
    std::fs::rename(&staged, &latest).map_err(io(&latest))?;
    Ok(dir)
}

/// The parent folder a tool's `--results DIR` names, else `default`.
pub fn parent_from_args(args: &[String], default: &str) -> PathBuf {
    args.iter()
        .position(|a| a == "--results")
        .and_then(|i| args.get(i + 1))
        .map_or_else(|| PathBuf::from(default), PathBuf::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_run_gets_a_folder_and_latest_follows() {
        let parent = tempfile::tempdir().unwrap();
        let first = create(parent.path()).unwrap();
        let second = create(parent.path()).unwrap();
        assert_ne!(first, second);
        assert_eq!(
            std::fs::canonicalize(parent.path().join("latest")).unwrap(),
            std::fs::canonicalize(&second).unwrap()
        );
        let name = second.file_name().unwrap().to_string_lossy().to_string();
        assert!(name.starts_with("20") && name.contains('_'), "{name}");
    }
}
