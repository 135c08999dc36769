//! File output that writes every file of a command or none of them.

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

/// Writes all `(path, bytes)` pairs or none.
///
/// Targets are checked first (no path twice, none an existing folder); then each file goes
/// to a temporary file beside its target, and only when all are written are they renamed
/// into place. On failure the temporary files are removed and no target is touched. The
/// renames themselves are not atomic as a group: a rename can only fail after the checks
/// if the file system changes under the command.
pub fn write_all_or_nothing(files: &[(&Path, &[u8])]) -> Result<(), WriteError> {
    let fail = |path: &Path, kind: io::ErrorKind, msg: &str| WriteError {
        path: path.to_path_buf(),
        source: io::Error::new(kind, msg.to_string()),
    };
    for (k, (path, _)) in files.iter().enumerate() {
        if files[..k].iter().any(|(p, _)| p == path) {
            return Err(fail(
                path,
                io::ErrorKind::InvalidInput,
                "named for two outputs of one command",
            ));
        }
        if path.is_dir() {
            return Err(fail(path, io::ErrorKind::IsADirectory, "is a folder"));
        }
    }
    let mut temps: Vec<PathBuf> = Vec::with_capacity(files.len());
    let cleanup = |temps: &[PathBuf]| {
        for t in temps {
            let _ = fs::remove_file(t);
        }
    };
    for (k, (path, bytes)) in files.iter().enumerate() {
        let tmp = temp_path(path, k);
        if let Err(source) = fs::write(&tmp, bytes) {
            cleanup(&temps);
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
            cleanup(&temps);
            return Err(WriteError {
                path: path.to_path_buf(),
                source,
            });
        }
    }
    Ok(())
}

fn temp_path(path: &Path, k: usize) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}-{k}.tmp", std::process::id()))
}

/// A named tensor for [`safetensors_bytes`]: name, dtype, shape, little-endian data.
pub type NamedTensor<'a> = (&'a str, safetensors::Dtype, Vec<usize>, Vec<u8>);

/// Serialises tensors with one metadata entry, `drape`, holding `meta` as JSON. One key
/// keeps the bytes deterministic (safetensors writes its metadata map in hash order).
pub fn safetensors_bytes(tensors: &[NamedTensor<'_>], meta: &impl serde::Serialize) -> Vec<u8> {
    let views: Vec<(&str, safetensors::tensor::TensorView<'_>)> = tensors
        .iter()
        .map(|(name, dtype, shape, data)| {
            (
                *name,
                safetensors::tensor::TensorView::new(*dtype, shape.clone(), data)
                    .expect("sizes match"),
            )
        })
        .collect();
    let mut info = std::collections::HashMap::new();
    info.insert(
        "drape".to_string(),
        serde_json::to_string(meta).expect("metadata serialises"),
    );
    safetensors::tensor::serialize(views, Some(info)).expect("tensors serialise")
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
    fn same_path_twice_and_folders_are_refused_before_writing() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.txt");
        let e = write_all_or_nothing(&[(&a, b"1"), (&a, b"2")]).unwrap_err();
        assert!(e.to_string().contains("two outputs"), "{e}");
        let sub = dir.path().join("sub");
        fs::create_dir(&sub).unwrap();
        let e = write_all_or_nothing(&[(&a, b"1"), (&sub, b"2")]).unwrap_err();
        assert!(e.to_string().contains("folder"), "{e}");
        assert_eq!(
            fs::read_dir(dir.path()).unwrap().count(),
            1,
            "only the folder itself"
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
