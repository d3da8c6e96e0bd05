//! A grid manifest's signature. Which cells make a grid, and its totals and bounds, are the
//! manifest's word: a grid compiled with a signing key signs its manifest as well as each cell,
//! so that a manifest edited to leave a cell out (or to list another grid's signed cell) is
//! refused, not read as a map without lanes there.
//!
//! A signed manifest starts with two lines,
//!
//! ```text
//! signer = "<the signer's ed25519 public key, 64 hex digits>"
//! signature = "<the ed25519 signature, 128 hex digits>"
//! ```
//!
//! followed by the manifest exactly as it was signed: the signature covers the text
//! `lanealign grid manifest` and a newline, then every byte after the second line. Both lines
//! are TOML, so the file stays one TOML document; an unsigned manifest has neither.

use ed25519_dalek::{Signature, Signer, VerifyingKey};

use crate::tile::{bytes_of_hex, hex, SigningKey};

/// What the signature covers before the manifest's bytes: a manifest's signature can never be
/// taken for another kind of document's.
const CONTEXT: &[u8] = b"lanealign grid manifest\n";

/// The message the signature of manifest text `body` covers.
fn message(body: &[u8]) -> Vec<u8> {
    [CONTEXT, body].concat()
}

/// `body` (a manifest's text) signed with `key`: the two signature lines, then `body`.
pub fn sign(body: &str, key: &SigningKey) -> String {
    let signature = key.sign(&message(body.as_bytes()));
    format!(
        "signer = \"{}\"\nsignature = \"{}\"\n{body}",
        hex(&key.verifying_key().to_bytes()),
        hex(&signature.to_bytes())
    )
}

/// Splits manifest bytes into the verified signer (`None`: unsigned) and the manifest text the
/// signature covers (all of `bytes` when unsigned). A manifest that starts as a signed one does
/// but whose lines are malformed, or whose signature does not match, is refused with why.
pub fn verify(bytes: &[u8]) -> Result<(Option<[u8; 32]>, &[u8]), String> {
    let Some(rest) = bytes.strip_prefix(b"signer = ") else {
        return Ok((None, bytes));
    };
    let (signer, rest) = quoted_line(rest, "signer")?;
    let rest = rest
        .strip_prefix(b"signature = ")
        .ok_or("a signed manifest's second line is its `signature = \"...\"`")?;
    let (signature, body) = quoted_line(rest, "signature")?;
    let signer: [u8; 32] =
        bytes_of_hex(signer).ok_or("signer: not 64 hex digits (an ed25519 public key)")?;
    let signature: [u8; 64] =
        bytes_of_hex(signature).ok_or("signature: not 128 hex digits (an ed25519 signature)")?;
    VerifyingKey::from_bytes(&signer)
        .map_err(|_| "signer: not an ed25519 public key")?
        .verify_strict(&message(body), &Signature::from_bytes(&signature))
        .map_err(|_| "the signature does not match the manifest: it was changed after signing")?;
    Ok((Some(signer), body))
}

/// The text of `"..."\n` at the start of `bytes`, and what follows the line.
fn quoted_line<'a>(bytes: &'a [u8], name: &str) -> Result<(&'a str, &'a [u8]), String> {
    let malformed = || format!("{name}: a line `{name} = \"<hex digits>\"`");
    let (line, rest) = bytes
        .iter()
        .position(|&b| b == b'\n')
        .map(|end| (&bytes[..end], &bytes[end + 1..]))
        .ok_or_else(malformed)?;
    let text = line
        .strip_prefix(b"\"")
        .and_then(|l| l.strip_suffix(b"\""))
        .and_then(|l| std::str::from_utf8(l).ok())
        .ok_or_else(malformed)?;
    Ok((text, rest))
}

#[cfg(test)]
mod tests {
    use super::*;

    const BODY: &str = "format = 2\ncell_size_m = 50.0\n";

    #[test]
    fn a_signed_manifest_verifies_and_any_change_is_refused() {
        let key = SigningKey::from_bytes(&[5; 32]);
        let signed = sign(BODY, &key);
        let (signer, body) = verify(signed.as_bytes()).unwrap();
        assert_eq!(signer, Some(key.verifying_key().to_bytes()));
        assert_eq!(body, BODY.as_bytes());
        assert_eq!(verify(BODY.as_bytes()).unwrap(), (None, BODY.as_bytes()));
        // The manifest changed, another key's line put in, the lines malformed or swapped.
        let other = hex(&SigningKey::from_bytes(&[6; 32]).verifying_key().to_bytes());
        let ours = hex(&key.verifying_key().to_bytes());
        let no_point = (0..=u8::MAX)
            .map(|b| [b; 32])
            .find(|bytes| VerifyingKey::from_bytes(bytes).is_err())
            .map(|bytes| hex(&bytes))
            .unwrap();
        for (crafted, why) in [
            (signed.replace("50.0", "51.0"), "does not match"),
            (signed.replace(&ours, &other), "does not match"),
            (format!("{signed}# a comment\n"), "does not match"),
            (signed.replacen("\"\n", "\n", 1), "a line `signer"),
            (signed.replacen(&ours, &ours[2..], 1), "not 64 hex digits"),
            (
                signed.replacen("signature = \"", "signature = \"+", 1),
                "not 128",
            ),
            (
                signed.replacen("\nsignature", "\nsignatures", 1),
                "second line",
            ),
            (signed.replacen(&ours, &no_point, 1), "not an ed25519"),
            (signed.replace('\n', "\r\n"), "a line `signer"),
        ] {
            let e = verify(crafted.as_bytes()).err();
            assert!(e.as_ref().is_some_and(|e| e.contains(why)), "{why}: {e:?}");
        }
    }
}
