//! Notices when the tile file the daemon loaded is changed by someone else. The daemon serves
//! from its own validated copy of the tile, so nothing it answers depends on the file; a change
//! is logged once (per change) so that an operator knows the file on disk and the map in use
//! differ, and that SIGHUP would load the new one.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// What identifies one version of a file: device, inode, length and modification time (ns).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Version {
    dev: u64,
    ino: u64,
    len: u64,
    mtime_ns: i128,
}

impl Version {
    fn of(path: &Path) -> Option<Version> {
        let m = std::fs::metadata(path).ok()?;
        Some(Version {
            dev: m.dev(),
            ino: m.ino(),
            len: m.len(),
            mtime_ns: i128::from(m.mtime()) * 1_000_000_000 + i128::from(m.mtime_nsec()),
        })
    }
}

/// Watches one tile file against the version that was loaded.
pub struct TileWatch {
    path: PathBuf,
    loaded: Option<Version>,
    last_seen: Option<Version>,
}

impl TileWatch {
    /// Starts watching `path`, whose current version is the one loaded.
    pub fn new(path: &Path) -> TileWatch {
        let loaded = Version::of(path);
        TileWatch {
            path: path.to_path_buf(),
            loaded,
            last_seen: loaded,
        }
    }

    /// What changed since the last call, described for a log line; `None` when nothing did.
    pub fn check(&mut self) -> Option<String> {
        let now = Version::of(&self.path);
        if now == self.last_seen {
            return None;
        }
        self.last_seen = now;
        let loaded = self.loaded?;
        Some(match now {
            None => "removed".to_string(),
            Some(v) if v == loaded => "restored to the loaded version".to_string(),
            Some(v) if (v.dev, v.ino) != (loaded.dev, loaded.ino) => {
                format!("replaced by another file ({} bytes)", v.len)
            }
            Some(v) if v.len < loaded.len => {
                format!("truncated in place ({} of {} bytes)", v.len, loaded.len)
            }
            Some(v) => format!("overwritten in place ({} bytes)", v.len),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_of_change_is_told_once() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tile");
        std::fs::write(&path, [1u8; 100]).unwrap();
        let mut watch = TileWatch::new(&path);
        assert_eq!(watch.check(), None);
        std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .unwrap()
            .set_len(10)
            .unwrap();
        assert_eq!(
            watch.check().unwrap(),
            "truncated in place (10 of 100 bytes)"
        );
        assert_eq!(watch.check(), None, "told once");
        let other = dir.path().join("new.tile");
        std::fs::write(&other, [2u8; 50]).unwrap();
        std::fs::rename(&other, &path).unwrap();
        assert!(watch.check().unwrap().starts_with("replaced"));
        std::fs::remove_file(&path).unwrap();
        assert_eq!(watch.check().unwrap(), "removed");
    }
}
