//! Files written whole or not at all. A process killed (or a disk filled) while saving must
//! leave the previous file as it was: every writer of the crate writes a temporary file in
//! the destination's folder, flushes it to disk, and renames it over the destination, which
//! POSIX and Windows both do in one step.
//!
//! The temporary file is created as any new file is (mode 0666 less the user's umask on
//! Unix), so a saved file gets the permissions the user's other tools give theirs. It is
//! named `.<name>.<pid>.<n>.tmp`; a process killed mid-save (SIGKILL, power loss) leaves it
//! behind, and the next save of the same destination removes those whose process is gone.
//! The Python writers (`viscache_rs.io.atomic_path`) name and clean theirs the same way.

use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};

/// Runs `write` on a temporary path beside `path`, then renames the result over `path`.
/// On any error the temporary file is removed and `path` is untouched. Temporary files of
/// `path` left by processes that no longer run are removed first
/// ([`remove_stale_temporaries`]).
pub fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let io = |source: std::io::Error| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    remove_stale_temporaries(path);
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

/// Removes the temporary files of `path` (`.<name>.<pid>.<n>.tmp` in its folder) whose
/// process `pid` no longer runs, and returns how many it removed. A file whose process is
/// alive, or whose liveness cannot be told (a platform without a check, a pid out of
/// range), is kept: it may be a save under way. Failures (an unreadable folder, a file
/// already gone) are ignored, since the save itself does not depend on them.
pub fn remove_stale_temporaries(path: &Path) -> usize {
    let (Some(name), Ok(entries)) = (path.file_name(), std::fs::read_dir(folder_of(path))) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(pid) = temporary_pid(&file, name) else {
            continue;
        };
        if pid != std::process::id()
            && process_is_gone(pid)
            && std::fs::remove_file(entry.path()).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// The folder `path` is in (`.` for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The pid in `file` when it is a temporary name of destination `name`:
/// `.<name>.<pid>.<n>.tmp` with both numbers decimal.
fn temporary_pid(file: &OsStr, name: &OsStr) -> Option<u32> {
    let (file, name) = (file.to_str()?, name.to_str()?);
    let rest = file
        .strip_prefix('.')?
        .strip_prefix(name)?
        .strip_prefix('.')?
        .strip_suffix(".tmp")?;
    let (pid, n) = rest.split_once('.')?;
    let decimal = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !(decimal(pid) && decimal(n)) {
        return None;
    }
    pid.parse().ok()
}

/// Whether no process `pid` runs (signal 0 probes without sending; ESRCH means none).
/// EPERM (another user's process) counts as running.
#[cfg(target_os = "linux")]
fn process_is_gone(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // pid 0 would probe the caller's process group, not a process.
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill with signal 0 only checks whether the process exists.
    let alive = unsafe { libc::kill(pid, 0) } == 0;
    !alive && std::io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH)
}

/// Without a liveness check the files are kept (a save under way must never lose its file).
#[cfg(not(target_os = "linux"))]
fn process_is_gone(_pid: u32) -> bool {
    false
}

/// Creates a fresh, empty file in `path`'s folder, `.<name>.<pid>.<n>.tmp`, and returns its
/// path; the writer then replaces its contents. Creating it exclusively reserves the name
/// against another writer of this process that counts its own `n` (the Python side). Fails
/// when `path` names no file (a folder, or an empty path).
fn temporary_beside(path: &Path) -> std::io::Result<PathBuf> {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name"))?;
    loop {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let mut temp = OsString::from(".");
        temp.push(name);
        temp.push(format!(".{}.{n}.tmp", std::process::id()));
        let temp = path.with_file_name(temp);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp)
        {
            Ok(_) => return Ok(temp),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
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

    #[test]
    fn temporary_names_are_recognised_for_their_destination_only() {
        let pid = |file: &str, name: &str| temporary_pid(OsStr::new(file), OsStr::new(name));
        assert_eq!(pid(".out.bin.123.0.tmp", "out.bin"), Some(123));
        assert_eq!(pid(".out.bin.4294967295.17.tmp", "out.bin"), Some(u32::MAX));
        // Another destination's, or not a temporary name at all.
        assert_eq!(pid(".out.bin.123.0.tmp", "out"), None);
        assert_eq!(pid(".out.123.0.tmp", "out.bin"), None);
        assert_eq!(pid("out.bin.123.0.tmp", "out.bin"), None);
        for bad in [
            ".out.bin.123.tmp",
            ".out.bin.12a.0.tmp",
            ".out.bin.123.0.1.tmp",
            ".out.bin..0.tmp",
            ".out.bin.-1.0.tmp",
            ".out.bin.99999999999.0.tmp",
            ".out.bin.123.0.tmpx",
        ] {
            assert_eq!(pid(bad, "out.bin"), None, "{bad}");
        }
    }

    /// A process killed mid-save (SIGKILL) leaves its temporary file; the next save of the
    /// same destination removes it, and never a file of a process that still runs.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_save_removes_temporaries_of_dead_processes_only() {
        let dir = std::env::temp_dir().join(format!("viscache_stale_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("out.bin");
        // A pid that has just ended: a child that has been waited for.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let live_other = std::os::unix::process::parent_id();
        let mine = std::process::id();
        let names = [
            format!(".out.bin.{dead}.3.tmp"),       // dead: removed
            format!(".out.bin.{live_other}.0.tmp"), // alive: kept
            format!(".out.bin.{mine}.999999.tmp"),  // this process's own: kept
            format!(".other.bin.{dead}.0.tmp"),     // another destination: kept
            ".out.bin.x.tmp".to_string(),           // not ours: kept
            ".out.bin.1.0.tmp".to_string(),         // pid 1 always runs: kept
        ];
        for n in &names {
            std::fs::write(dir.join(n), b"partial").unwrap();
        }
        write_bytes_atomically(&path, b"saved").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"saved");
        let mut left: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        let mut expected: Vec<String> = names[1..].to_vec();
        expected.push("out.bin".to_string());
        expected.sort();
        assert_eq!(left, expected);
        // Nothing else is stale now.
        assert_eq!(remove_stale_temporaries(&path), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Saved files get the permissions of any new file: 0666 less the umask (the
    /// temporary file is not created private).
    #[cfg(target_os = "linux")]
    #[test]
    fn a_saved_file_follows_the_umask() {
        use std::os::unix::fs::PermissionsExt;
        // Reading the umask means setting it: put the same value straight back.
        // SAFETY: umask only swaps the process's file-creation mask.
        let umask = unsafe {
            let old = libc::umask(0o022);
            libc::umask(old);
            old
        };
        let dir = std::env::temp_dir().join(format!("viscache_mode_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("out.bin");
        write_bytes_atomically(&path, b"saved").unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o666 & !umask, "umask {umask:o}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
