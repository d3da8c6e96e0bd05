//! Signing keys for tiles and grids: the secret key file `lanealign-map keygen` writes (64 hex
//! digits, the ed25519 seed, mode 0600), read for `compile --sign` and the Python package's
//! `compile_map(sign=...)`, which warn when others may read it.

use std::path::{Path, PathBuf};

use lanealign_core::input::{read_regular_file, InputError};
use lanealign_core::tile::{parse_key_hex, SigningKey};

/// The largest key file read (bytes): a key is 64 hex digits and a newline.
const MAX_KEY_FILE_BYTES: u64 = 1024;

/// A key file that could not be read as a signing key.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// The file could not be read (missing, not a regular file, too long).
    #[error(transparent)]
    Input(#[from] InputError),
    /// The file does not hold 64 hex digits.
    #[error("{path}: not a key file from `lanealign-map keygen` (64 hex digits)")]
    NotAKey {
        /// The file.
        path: PathBuf,
    },
    /// A public key given is neither 64 hex digits nor a file holding them.
    #[error("{given:?}: not a public key (64 hex digits, or a file holding them such as keygen's KEY.pub)")]
    NotAPublicKey {
        /// What was given.
        given: String,
    },
}

/// The 32-byte key a key file holds as 64 hex digits (`None`: it holds something else).
fn key_in(path: &Path) -> Result<Option<[u8; 32]>, InputError> {
    let bytes = read_regular_file(path, MAX_KEY_FILE_BYTES)?;
    Ok(std::str::from_utf8(&bytes).ok().and_then(parse_key_hex))
}

/// The signing key in `path`, a secret key file from `lanealign-map keygen`.
pub fn read_secret_key(path: &Path) -> Result<SigningKey, KeyError> {
    let seed = key_in(path)?.ok_or_else(|| KeyError::NotAKey {
        path: path.to_path_buf(),
    })?;
    Ok(SigningKey::from_bytes(&seed))
}

/// A public key given as 64 hex digits, or as a file holding them (`lanealign-map keygen`'s
/// `KEY.pub`).
pub fn read_public_key(given: &str) -> Result<[u8; 32], KeyError> {
    if let Some(key) = parse_key_hex(given) {
        return Ok(key);
    }
    key_in(Path::new(given))
        .ok()
        .flatten()
        .ok_or_else(|| KeyError::NotAPublicKey {
            given: given.to_string(),
        })
}

/// What to tell when the secret key file at `path` may be read by others than its owner (its
/// mode allows group or world access), as ssh does of private keys: anyone who can read it can
/// sign maps a vehicle trusts. `None` when only the owner can (or the file's mode cannot be
/// read: [`read_secret_key`] then says why).
pub fn exposure(path: &Path) -> Option<String> {
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(path).ok()?.permissions().mode() & 0o777;
    (mode & 0o077 != 0).then(|| {
        format!(
            "{}: the secret key may be read by others (mode {mode:03o}): anyone who can read it \
             can sign maps your vehicles trust; `chmod 600` it",
            path.display()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_file_holds_64_hex_digits() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("builder.key");
        std::fs::write(&path, format!("{}\n", "07".repeat(32))).unwrap();
        let key = read_secret_key(&path).unwrap();
        assert_eq!(key.to_bytes(), [7; 32]);
        for text in [
            "07".repeat(31),
            "+7".repeat(32),
            "x".into(),
            "0".repeat(2000),
        ] {
            std::fs::write(&path, &text).unwrap();
            let e = read_secret_key(&path).err().unwrap().to_string();
            assert!(e.contains("builder.key"), "{text}: {e}");
        }
        let e = read_secret_key(&dir.path().join("missing.key")).err();
        assert!(matches!(e, Some(KeyError::Input(_))), "{e:?}");
    }

    #[test]
    fn a_public_key_is_hex_digits_or_a_file_of_them() {
        let dir = tempfile::tempdir().unwrap();
        let public = dir.path().join("builder.key.pub");
        std::fs::write(&public, format!("{}\n", "0a".repeat(32))).unwrap();
        let path = public.to_str().unwrap();
        assert_eq!(read_public_key(&"0a".repeat(32)).unwrap(), [10; 32]);
        assert_eq!(read_public_key(path).unwrap(), [10; 32]);
        let missing = dir.path().join("missing.pub");
        for given in ["0a".repeat(31), missing.to_str().unwrap().to_string()] {
            let e = read_public_key(&given).err().unwrap().to_string();
            assert!(e.contains("not a public key"), "{given}: {e}");
        }
    }

    #[test]
    fn a_key_others_may_read_is_told() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("builder.key");
        std::fs::write(&path, "07".repeat(32)).unwrap();
        for (mode, told) in [(0o600, false), (0o400, false), (0o640, true), (0o604, true)] {
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
            let said = exposure(&path);
            assert_eq!(said.is_some(), told, "{mode:o}: {said:?}");
            if let Some(text) = said {
                assert!(text.contains(&format!("mode {mode:03o}")), "{text}");
            }
        }
        assert_eq!(exposure(&dir.path().join("missing.key")), None);
    }
}
