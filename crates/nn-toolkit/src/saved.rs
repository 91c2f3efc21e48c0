//! Helpers of the files a saved model is made of, shared by every crate that writes or reads
//! them (the QUADFormer checkpoint, the baselines' saved states, model directories): whether a
//! listed file is a plain name inside its directory, the SHA-256 recorded for each file, and the
//! one wording of a malformed JSON file's error.

use std::path::Path;

/// Whether `name` is a plain file name: one normal path component (no `/`, `\`, `..`, root).
#[must_use]
pub fn is_plain_name(name: &str) -> bool {
    !name.contains(['/', '\\']) && Path::new(name).file_name().is_some_and(|n| n == name)
}

/// Lower-case hex SHA-256 of `bytes`, as the manifests record it.
#[must_use]
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest as _;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// `malformed {what} at line L, column C: message`, the position said once (serde_json's own
/// message repeats it at its end).
#[must_use]
pub fn malformed_json(what: &str, e: &serde_json::Error) -> String {
    let msg = e.to_string();
    let msg = match msg.rsplit_once(" at line ") {
        Some((head, _)) if e.line() > 0 => head.to_owned(),
        _ => msg,
    };
    format!("malformed {what} at line {}, column {}: {msg}", e.line(), e.column())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_names_are_single_components() {
        assert!(is_plain_name("quadformer.json"));
        for bad in ["", ".", "..", "a/b", "/etc/passwd", "a\\b", "../x"] {
            assert!(!is_plain_name(bad), "{bad}");
        }
    }

    #[test]
    fn the_position_is_said_once() {
        let e = serde_json::from_str::<u32>("\"x\"").unwrap_err();
        let msg = malformed_json("manifest", &e);
        assert!(msg.starts_with("malformed manifest at line 1, column 3: "), "{msg}");
        assert_eq!(msg.matches("line").count(), 1, "{msg}");
    }
}
