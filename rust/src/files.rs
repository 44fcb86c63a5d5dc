//! Files written whole or not at all. A process killed (or a disk filled) while saving must
//! leave the previous file as it was: every writer of the crate writes a temporary file in
//! the destination's folder, flushes it to disk, and renames it over the destination, which
//! POSIX and Windows both do in one step.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};

/// Runs `write` on a temporary path beside `path`, then renames the result over `path`.
/// On any error the temporary file is removed and `path` is untouched.
pub fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let io = |source: std::io::Error| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let temp = temporary_beside(path).map_err(io)?;
    let written = write(&temp).and_then(|()| {
        // Flush the data before the rename makes it the file: a crash after the rename
        // must not find it empty.
        std::fs::File::open(&temp)
            .and_then(|f| f.sync_all())
            .map_err(io)?;
        std::fs::rename(&temp, path).map_err(io)
    });
    if written.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    written
}

/// Writes `bytes` to `path` with [`write_atomically`].
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |temp| {
        std::fs::write(temp, bytes).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// A fresh name in `path`'s folder: `.<name>.<pid>.<n>.tmp`. Fails when `path` names no
/// file (a folder, or an empty path).
fn temporary_beside(path: &Path) -> std::io::Result<PathBuf> {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name"))?;
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let mut temp = std::ffi::OsString::from(".");
    temp.push(name);
    temp.push(format!(".{}.{n}.tmp", std::process::id()));
    Ok(path.with_file_name(temp))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = std::env::temp_dir().join(format!("viscache_files_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("out.bin");
        write_bytes_atomically(&path, b"first").unwrap();
        let failed = write_atomically(&path, |temp| {
            std::fs::write(temp, b"half").unwrap();
            Err(Error::invalid("image", "failed on purpose"))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        write_bytes_atomically(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
        assert!(write_bytes_atomically(&dir.join(".."), b"x").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
