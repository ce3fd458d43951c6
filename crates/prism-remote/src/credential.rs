//! The shared secret a trainer presents to `prism serve`: read from a file (or the
//! environment), never from the command line, where other users of the machine see it.

use std::path::{Path, PathBuf};

/// The environment variable holding the token when no `--token-file` is given.
pub const TOKEN_ENV: &str = "PRISM_TOKEN";

/// The shortest token accepted, in bytes: a shorter one can be guessed.
pub const MIN_TOKEN_BYTES: usize = 16;

/// Why no token could be read.
#[derive(Debug, thiserror::Error)]
pub enum CredentialError {
    /// Neither `--token-file` nor the environment gives one.
    #[error(
        "no credential: pass --token-file FILE (a file holding the shared token) or set \
         {TOKEN_ENV}"
    )]
    Missing,
    /// The token file cannot be read.
    #[error("cannot read the token file {}: {source}", path.display())]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file (or the variable) is empty.
    #[error("the token in {0} is empty")]
    Empty(String),
    /// The token is too short to resist guessing.
    #[error(
        "the token in {origin} has {len} bytes, fewer than {MIN_TOKEN_BYTES}: make a good one \
         with `openssl rand -hex 32 > token` and copy that file to every machine"
    )]
    TooShort {
        /// Where it was read from.
        origin: String,
        /// Its length in bytes.
        len: usize,
    },
}

/// The token in `file` (surrounding white space removed), else in `$PRISM_TOKEN`.
///
/// # Errors
/// No token anywhere, an unreadable file, an empty token or one shorter than
/// [`MIN_TOKEN_BYTES`].
pub fn read_token(file: Option<&Path>) -> Result<String, CredentialError> {
    let (token, origin) = match file {
        Some(path) => (
            std::fs::read_to_string(path).map_err(|source| CredentialError::Unreadable {
                path: path.to_path_buf(),
                source,
            })?,
            path.display().to_string(),
        ),
        None => match std::env::var(TOKEN_ENV) {
            Ok(token) => (token, format!("${TOKEN_ENV}")),
            Err(_) => return Err(CredentialError::Missing),
        },
    };
    let token = token.trim();
    if token.is_empty() {
        return Err(CredentialError::Empty(origin));
    }
    if token.len() < MIN_TOKEN_BYTES {
        return Err(CredentialError::TooShort {
            origin,
            len: token.len(),
        });
    }
    Ok(token.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_is_read_and_trimmed_and_bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("token");
        std::fs::write(&file, "s3cret-of-16-bytes\n").unwrap();
        assert_eq!(read_token(Some(&file)).unwrap(), "s3cret-of-16-bytes");

        std::fs::write(&file, "abcd\n").unwrap();
        let err = read_token(Some(&file)).unwrap_err().to_string();
        assert!(
            err.contains("4 bytes") && err.contains("16") && err.contains("openssl rand"),
            "{err}"
        );

        std::fs::write(&file, " \n").unwrap();
        let err = read_token(Some(&file)).unwrap_err().to_string();
        assert!(err.contains("empty") && err.contains("token"), "{err}");

        let missing = dir.path().join("absent");
        let err = read_token(Some(&missing)).unwrap_err().to_string();
        assert!(err.contains("absent"), "{err}");
    }
}
