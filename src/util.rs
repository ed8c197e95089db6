//! Small helpers shared across modules.

use std::io::Write;
use std::path::{Path, PathBuf};

/// A temporary sibling name for `path` (same directory, so the rename is atomic).
pub fn temp_sibling(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// Checks, before any work, that files can be created in the folder `dir` (or, when it
/// does not exist yet, in its nearest existing ancestor, where it would be created).
/// Leaves nothing behind.
pub fn check_writable_dir(dir: &Path) -> std::io::Result<()> {
    let mut d = dir.to_path_buf();
    if d.as_os_str().is_empty() {
        d = PathBuf::from(".");
    }
    loop {
        match std::fs::metadata(&d) {
            Ok(m) if m.is_dir() => break,
            Ok(_) => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::NotADirectory,
                    format!("{} is a file, not a folder", d.display()),
                ));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => match d.parent() {
                Some(p) if !p.as_os_str().is_empty() => d = p.to_path_buf(),
                _ => {
                    d = PathBuf::from(".");
                    break;
                }
            },
            Err(e) => return Err(e),
        }
    }
    let probe = d.join(format!(".synosis-write-test-{}", std::process::id()));
    std::fs::File::create(&probe).map_err(|e| {
        std::io::Error::new(e.kind(), format!("cannot write into {}: {e}", d.display()))
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Writes `bytes` to a temporary name beside `path`, syncs, and renames it into place,
/// so a reader (or a killed run) never sees a half-written file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by a closure writing to the file.
pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let tmp = temp_sibling(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        write(&mut f)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
