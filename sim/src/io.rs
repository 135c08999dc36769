//! File output that either writes every file of a command or none of them.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// An output file could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path}: {source}")]
pub struct WriteError {
    /// The file that could not be written.
    pub path: PathBuf,
    /// What the operating system said.
    #[source]
    pub source: io::Error,
}

/// Writes all `(path, bytes)` pairs or none: each goes to a temporary file beside its
/// target first; only when every temporary file is written are they renamed into place.
/// On failure the temporary files are removed and no target is touched.
pub fn write_all_or_nothing(files: &[(&Path, &[u8])]) -> Result<(), WriteError> {
    let mut temps: Vec<PathBuf> = Vec::with_capacity(files.len());
    for (path, bytes) in files {
        let tmp = temp_path(path);
        if let Err(source) = fs::write(&tmp, bytes) {
            for t in &temps {
                let _ = fs::remove_file(t);
            }
            let _ = fs::remove_file(&tmp);
            return Err(WriteError {
                path: path.to_path_buf(),
                source,
            });
        }
        temps.push(tmp);
    }
    for ((path, _), tmp) in files.iter().zip(&temps) {
        if let Err(source) = fs::rename(tmp, path) {
            for t in &temps {
                let _ = fs::remove_file(t);
            }
            return Err(WriteError {
                path: path.to_path_buf(),
                source,
            });
        }
    }
    Ok(())
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failing_second_file_leaves_no_trace() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("a.txt");
        let bad = dir.path().join("missing-dir").join("b.txt");
        let err = write_all_or_nothing(&[(&good, b"a"), (&bad, b"b")]).unwrap_err();
        assert_eq!(err.path, bad);
        assert_eq!(
            fs::read_dir(dir.path()).unwrap().count(),
            0,
            "nothing may be left behind"
        );
    }

    #[test]
    fn writes_every_file() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.txt");
        let b = dir.path().join("b.txt");
        write_all_or_nothing(&[(&a, b"1"), (&b, b"22")]).unwrap();
        assert_eq!(fs::read(&a).unwrap(), b"1");
        assert_eq!(fs::read(&b).unwrap(), b"22");
    }
}
