//! The newest map version a namespace's daemon has served, kept in its state folder so that a
//! restart does not go back to an older map any more than SIGHUP does. An older map signed by a
//! trusted key verifies as well as the newest; without this record, a daemon made to restart
//! (killed, or the machine rebooted) would serve one put in the configured place, down to
//! `min_map_version`. A deliberate step back removes the record.

use std::path::{Path, PathBuf};

use lanealign_core::input::{read_regular_file, InputError};

use crate::journal::{write_durably, JournalError};

/// The record's file name in the namespace's state folder.
pub const FILE_NAME: &str = "served_map_version";

/// The longest record read: a u64 in decimal and a newline are 21 bytes.
const MAX_LEN: u64 = 64;

/// The record cannot be read or written, or the map is older than it.
#[derive(Debug, thiserror::Error)]
pub enum ServedMapError {
    /// The record exists but cannot be read (a folder in its place, unreadable).
    #[error(transparent)]
    Read(#[from] InputError),
    /// The record does not hold a version.
    #[error("{path}: {detail}: the record of the newest map version served is damaged; if nobody changed it, remove it (the daemon then serves any map at or above min_map_version and records it again)")]
    Damaged {
        /// The record.
        path: PathBuf,
        /// What is wrong with it.
        detail: String,
    },
    /// The map is older than the newest served.
    #[error("map version {map_version} is older than {served}, the newest this namespace's daemon has served (recorded in {path}): an older map put in its place? Build the current one with a larger --map-version; to go back deliberately, remove {path}")]
    Older {
        /// The map's version.
        map_version: u64,
        /// The newest version served.
        served: u64,
        /// The record.
        path: PathBuf,
    },
    /// The record could not be written.
    #[error(transparent)]
    Write(#[from] JournalError),
}

/// The record in one namespace's state folder.
#[derive(Debug, Clone)]
pub struct ServedMap {
    path: PathBuf,
}

impl ServedMap {
    /// The record of the namespace whose state folder is `dir` (it need not exist yet).
    pub fn in_dir(dir: &Path) -> ServedMap {
        ServedMap {
            path: dir.join(FILE_NAME),
        }
    }

    /// The record's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The newest map version served, `None` when nothing is recorded (no daemon has served a
    /// map here, or the record was removed).
    pub fn newest(&self) -> Result<Option<u64>, ServedMapError> {
        let bytes = match read_regular_file(&self.path, MAX_LEN) {
            Ok(bytes) => bytes,
            Err(InputError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
                return Ok(None)
            }
            Err(e) => return Err(e.into()),
        };
        let damaged = |detail: &str| ServedMapError::Damaged {
            path: self.path.clone(),
            detail: detail.into(),
        };
        let text = std::str::from_utf8(&bytes).map_err(|_| damaged("not text"))?;
        let digits = text.strip_suffix('\n').unwrap_or(text);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Err(damaged("not a version (decimal digits and a newline)"));
        }
        let version = digits
            .parse()
            .map_err(|_| damaged("a version beyond 2^64 - 1"))?;
        Ok(Some(version))
    }

    /// Refuses a map older than the newest served; returns the newest served.
    pub fn check(&self, map_version: u64) -> Result<Option<u64>, ServedMapError> {
        let newest = self.newest()?;
        match newest {
            Some(served) if map_version < served => Err(ServedMapError::Older {
                map_version,
                served,
                path: self.path.clone(),
            }),
            _ => Ok(newest),
        }
    }

    /// Records, durably, that a map of `map_version` is served, refusing one older than the
    /// newest served. The record's own version leaves it as it is.
    pub fn record(&self, map_version: u64) -> Result<(), ServedMapError> {
        if self.check(map_version)? != Some(map_version) {
            write_durably(&self.path, format!("{map_version}\n").as_bytes())?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, rng_seed: proptest::test_runner::RngSeed::Fixed(7), ..ProptestConfig::default() })]
        /// Any bytes in the record's place: a version only when they are one written as the
        /// daemon writes it (or without its newline), a refusal otherwise, never a panic.
        #[test]
        fn any_record_is_read_or_refused(bytes in prop_oneof![
            proptest::collection::vec(any::<u8>(), 0..40),
            "[0-9]{0,22}\n?".prop_map(String::into_bytes),
        ]) {
            let dir = tempfile::tempdir().unwrap();
            let record = ServedMap::in_dir(dir.path());
            std::fs::write(record.path(), &bytes).unwrap();
            let digits = bytes.strip_suffix(b"\n").unwrap_or(&bytes);
            let canonical = std::str::from_utf8(digits)
                .ok()
                .filter(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
                .and_then(|d| d.parse::<u64>().ok());
            match record.newest() {
                Ok(version) => prop_assert_eq!(version, canonical),
                Err(e) => {
                    prop_assert!(canonical.is_none(), "{:?} refused: {}", bytes, e);
                    prop_assert!(matches!(e, ServedMapError::Damaged { .. }), "{}", e);
                }
            }
        }
    }

    #[test]
    fn the_record_only_rises_and_refuses_older_maps() {
        let dir = tempfile::tempdir().unwrap();
        let record = ServedMap::in_dir(dir.path());
        assert_eq!(record.newest().unwrap(), None, "nothing recorded yet");
        record.record(5).unwrap();
        assert_eq!(std::fs::read_to_string(record.path()).unwrap(), "5\n");
        record.record(5).unwrap();
        assert_eq!(record.check(7).unwrap(), Some(5));
        let e = record.record(4).unwrap_err().to_string();
        assert!(
            e.contains("map version 4 is older than 5") && e.contains("remove"),
            "{e}"
        );
        assert_eq!(
            record.newest().unwrap(),
            Some(5),
            "a refusal changes nothing"
        );
        record.record(u64::MAX).unwrap();
        assert_eq!(record.newest().unwrap(), Some(u64::MAX));
        std::fs::remove_file(record.path()).unwrap();
        record.record(4).unwrap();
        assert_eq!(
            record.newest().unwrap(),
            Some(4),
            "removed: a deliberate step back"
        );
    }

    #[test]
    fn a_damaged_record_is_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let record = ServedMap::in_dir(dir.path());
        for bad in [
            &b""[..],
            b"\n",
            b"-1\n",
            b" 5\n",
            b"5\n\n",
            b"0x10",
            b"\xff\xfe",
            b"18446744073709551616\n",
        ] {
            std::fs::write(record.path(), bad).unwrap();
            let e = record.check(9).unwrap_err();
            assert!(matches!(e, ServedMapError::Damaged { .. }), "{bad:?}: {e}");
            assert!(e.to_string().contains(FILE_NAME), "{e}");
        }
        std::fs::write(record.path(), vec![b'1'; 100]).unwrap();
        assert!(matches!(
            record.check(9).unwrap_err(),
            ServedMapError::Read(InputError::TooLarge { .. })
        ));
        std::fs::remove_file(record.path()).unwrap();
        std::fs::create_dir(record.path()).unwrap();
        assert!(matches!(
            record.check(9).unwrap_err(),
            ServedMapError::Read(_)
        ));
    }
}
