//! Files a glTF document names: only `data:` URIs and files inside the document's own folder
//! are ever read, and every read is bounded.
//!
//! A glTF names its buffers and images by URI. A hostile file could name `/etc/passwd`,
//! `../../home/me/.ssh/id_rsa` or a symbolic link to either; a tool that read it would copy
//! the bytes into its output. So a URI is refused, before anything is opened, when it has a
//! scheme other than `data:` (`file:`, `http:` …), is absolute (`/…`, `\…`, `//host/…`), or
//! climbs above the folder with `..`; what is left is resolved with symbolic links followed
//! and refused unless it lands inside the folder (canonical paths compared).

use std::io::{self, Read};
use std::path::{Component, Path, PathBuf};

/// Longest part of a URI (or other input) quoted in an error message.
pub const SHOWN_CHARS: usize = 80;

/// `text` cut to [`SHOWN_CHARS`] characters (with `…` when cut) and its control characters
/// escaped ([`mouthpiece_output::shown()`]), for messages and reports: a name from a file never
/// reaches the terminal raw.
pub fn shown(text: &str) -> String {
    let mut chars = text.chars();
    let head: String = chars.by_ref().take(SHOWN_CHARS).collect();
    let head = mouthpiece_output::shown(&head).into_owned();
    if chars.next().is_some() {
        format!("{head}…")
    } else {
        head
    }
}

/// Reads a file of at most `limit` bytes; a longer one (a device such as `/dev/zero`, a FIFO
/// that never ends) is an `InvalidData` error naming the limit, read no further than it.
pub fn read_bounded(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    let mut bytes = Vec::new();
    // A regular file says its size: a large one is refused without reading it.
    if !(meta.is_file() && meta.len() > limit) {
        file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    }
    if (meta.is_file() && meta.len() > limit) || bytes.len() as u64 > limit {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("longer than {limit} bytes"),
        ));
    }
    Ok(bytes)
}

/// Why a URI may not be read; the message follows the URI (`URI `x` is empty`).
#[derive(Debug, thiserror::Error)]
pub enum UriError {
    #[error("is empty")]
    Empty,
    #[error("has a scheme: only `data:` URIs and files beside the document are read")]
    Scheme,
    #[error("is an absolute path: only files beside the document are read")]
    Absolute,
    #[error("is not UTF-8 once its %-escapes are undone")]
    NotUtf8,
    #[error("holds a NUL character")]
    Nul,
    #[error("climbs out of the document's folder with `..`")]
    Climbs,
    #[error("names the folder itself, not a file")]
    Folder,
    #[error("cannot be found next to the document: {0}")]
    NotFound(io::Error),
    #[error("leads outside the document's folder {} (through a symbolic link)", .0.display())]
    Outside(PathBuf),
    #[error("the document's folder {}: {cause}", folder.display())]
    DocumentFolder { folder: PathBuf, cause: io::Error },
}

/// The file a (non-`data:`) URI names, relative to `folder` (the folder of the document that
/// holds the URI), or why it may not be read. Nothing is opened: the checks are on the text
/// and on the canonical paths. The file must exist (symbolic links are followed to see where
/// they land).
pub fn resolve_inside(folder: &Path, uri: &str) -> Result<PathBuf, UriError> {
    let relative = relative_path(uri)?;
    let folder = canonical_folder(folder)?;
    let target = folder
        .join(&relative)
        .canonicalize()
        .map_err(UriError::NotFound)?;
    if !target.starts_with(&folder) {
        return Err(UriError::Outside(folder));
    }
    Ok(target)
}

/// Like [`resolve_inside`] for a file that is named but never read (an image): the URI must
/// stay inside `folder` by its text, and, when the file exists, by its canonical path; a
/// missing file is no error.
pub fn check_inside(folder: &Path, uri: &str) -> Result<(), UriError> {
    let relative = relative_path(uri)?;
    let Ok(folder) = folder.canonicalize() else {
        return Ok(());
    };
    match folder.join(&relative).canonicalize() {
        Ok(target) if !target.starts_with(&folder) => Err(UriError::Outside(folder)),
        _ => Ok(()),
    }
}

fn canonical_folder(folder: &Path) -> Result<PathBuf, UriError> {
    let folder = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    folder
        .canonicalize()
        .map_err(|cause| UriError::DocumentFolder {
            folder: folder.to_path_buf(),
            cause,
        })
}

/// A relative URI reference as a relative path that stays below its folder by its text.
fn relative_path(uri: &str) -> Result<PathBuf, UriError> {
    if uri.is_empty() {
        return Err(UriError::Empty);
    }
    if has_scheme(uri) {
        return Err(UriError::Scheme);
    }
    if uri.starts_with(['/', '\\']) {
        return Err(UriError::Absolute);
    }
    // RFC 3986 relative reference: drop a query or fragment, undo %-escapes (`%20`).
    let path_part = uri.split(['?', '#']).next().unwrap_or_default();
    let decoded = percent_encoding::percent_decode_str(path_part)
        .decode_utf8()
        .map_err(|_| UriError::NotUtf8)?;
    if decoded.contains('\0') {
        return Err(UriError::Nul);
    }
    let path = PathBuf::from(decoded.as_ref());
    let mut depth = 0usize;
    for component in path.components() {
        match component {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir if depth > 0 => depth -= 1,
            Component::ParentDir => return Err(UriError::Climbs),
            Component::RootDir | Component::Prefix(_) => return Err(UriError::Absolute),
        }
    }
    if depth == 0 {
        return Err(UriError::Folder);
    }
    Ok(path)
}

/// `scheme:` at the start (RFC 3986: a letter, then letters, digits, `+`, `-`, `.`).
fn has_scheme(uri: &str) -> bool {
    let Some((scheme, _)) = uri.split_once(':') else {
        return false;
    };
    let mut chars = scheme.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uris_that_leave_the_folder_are_refused_before_anything_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("asset");
        std::fs::create_dir_all(inner.join("sub")).unwrap();
        std::fs::write(inner.join("sub/mesh data.bin"), b"ok").unwrap();
        std::fs::write(dir.path().join("secret"), b"secret").unwrap();
        std::os::unix::fs::symlink(dir.path().join("secret"), inner.join("link.bin")).unwrap();
        let ok = resolve_inside(&inner, "sub/mesh%20data.bin").unwrap();
        assert_eq!(ok, inner.canonicalize().unwrap().join("sub/mesh data.bin"));
        assert!(resolve_inside(&inner, "./sub/../sub/mesh%20data.bin").is_ok());
        for (uri, why) in [
            ("/etc/passwd", "absolute"),
            ("//host/share/x.bin", "absolute"),
            ("\\etc\\passwd", "absolute"),
            ("file:///etc/passwd", "scheme"),
            ("C:/Windows/win.ini", "scheme"),
            ("../secret", "climbs"),
            ("sub/../../secret", "climbs"),
            ("%2e%2e/secret", "climbs"),
            ("%2Fetc%2Fpasswd", "absolute"),
            ("link.bin", "symbolic link"),
            ("missing.bin", "cannot be found"),
            ("", "empty"),
            (".", "folder itself"),
        ] {
            let err = resolve_inside(&inner, uri).unwrap_err().to_string();
            assert!(err.contains(why), "{uri}: {err}");
        }
        assert!(check_inside(&inner, "missing.png").is_ok());
        assert!(check_inside(&inner, "link.bin").is_err());
        assert!(check_inside(&inner, "../secret.png").is_err());
    }

    #[test]
    fn reads_are_bounded_and_shown_text_is_cut() {
        let err = read_bounded(Path::new("/dev/zero"), 1000).unwrap_err();
        assert!(err.to_string().contains("longer than 1000 bytes"), "{err}");
        assert_eq!(shown("abc"), "abc");
        assert_eq!(shown("a\u{1b}[2J\nb"), "a\\u{1b}[2J\\nb");
        let long = "x".repeat(10_000);
        assert_eq!(shown(&long).chars().count(), SHOWN_CHARS + 1);
    }
}
