//! Shared helpers of the line-based text formats (OBJ and MTL).

use std::path::Path;

use super::error::ScanError;

/// Reads a text file; bytes that are not UTF-8 (comments in a local encoding) are replaced
/// rather than rejected.
pub(crate) fn read_text(path: &Path) -> Result<String, ScanError> {
    let bytes = std::fs::read(path).map_err(|source| ScanError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// The logical lines of a text file with their 1-based line numbers: comments (`#` to the
/// end of the line) removed, lines ending in `\` joined with the next, blank lines skipped.
pub(crate) fn logical_lines(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim_end();
        let (start, mut joined) = pending.take().unwrap_or((i + 1, String::new()));
        if let Some(body) = line.strip_suffix('\\') {
            joined.push_str(body);
            joined.push(' ');
            pending = Some((start, joined));
            continue;
        }
        joined.push_str(line);
        if !joined.trim().is_empty() {
            out.push((start, joined.trim().to_string()));
        }
    }
    if let Some((start, joined)) = pending.filter(|(_, j)| !j.trim().is_empty()) {
        out.push((start, joined.trim().to_string()));
    }
    out
}

/// Parses `count` (or between `min` and `max`) floats from whitespace-separated tokens.
pub(crate) fn floats(
    tokens: &[&str],
    min: usize,
    max: usize,
    path: &Path,
    line: usize,
    what: &str,
) -> Result<Vec<f32>, ScanError> {
    if tokens.len() < min || tokens.len() > max {
        let expected = if min == max {
            format!("{min}")
        } else {
            format!("{min} to {max}")
        };
        return Err(ScanError::syntax(
            path,
            line,
            format!("{what} needs {expected} numbers, found {}", tokens.len()),
        ));
    }
    tokens
        .iter()
        .map(|t| {
            t.parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    ScanError::syntax(path, line, format!("{what}: '{t}' is not a finite number"))
                })
        })
        .collect()
}
