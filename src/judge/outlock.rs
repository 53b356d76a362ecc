//! The exclusive lock on a run's output folder: two runs into the same
//! `--out` would delete and read each other's per-case results. The lock is
//! `flock` on `<out>/.hpjudge.lock`, which holds who took it; the kernel
//! drops it when the holder exits, however it exits (kill -9 included).

use std::fs::File;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use super::load::JudgeInputError;

/// Held for the life of a run; dropping it releases the lock.
pub struct OutLock {
    _file: File,
    pub path: PathBuf,
}

/// The lock file's name inside the output folder.
pub const LOCK_FILE: &str = ".hpjudge.lock";

/// Takes the lock on `out` (which must exist), or refuses naming the holder.
pub fn lock_out_dir(out: &Path, what: &str) -> Result<OutLock, JudgeInputError> {
    let path = out.join(LOCK_FILE);
    let at = out.display().to_string();
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| {
            JudgeInputError::new(&at, "", format!("cannot open {}: {e}", path.display()))
        })?;
    if !try_lock(&f) {
        let mut holder = String::new();
        let _ = f.read_to_string(&mut holder);
        let holder = holder.trim();
        let holder = if holder.is_empty() {
            "another hpjudge process"
        } else {
            holder
        };
        return Err(JudgeInputError::new(
            &at,
            "",
            format!("output folder is in use by {holder}; wait for it or choose another --out"),
        ));
    }
    let me = format!(
        "hpjudge pid {} ({what}) since unix time {}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs())
    );
    let _ = f.set_len(0);
    let _ = f.rewind();
    let _ = f.write_all(me.as_bytes());
    let _ = f.flush();
    Ok(OutLock { _file: f, path })
}

#[cfg(unix)]
fn try_lock(f: &File) -> bool {
    use std::os::unix::io::AsRawFd;
    // SAFETY: flock on a file descriptor this function's caller owns.
    unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) == 0 }
}

#[cfg(not(unix))]
fn try_lock(_: &File) -> bool {
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_the_same_folder_is_refused_naming_the_holder() {
        let d = std::env::temp_dir().join(format!("hp-lock-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let first = lock_out_dir(&d, "run a.yaml").unwrap();
        let e = lock_out_dir(&d, "run b.yaml").err().unwrap().to_string();
        assert!(
            e.contains("in use by hpjudge pid") && e.contains("run a.yaml"),
            "{e}"
        );
        drop(first);
        assert!(lock_out_dir(&d, "run b.yaml").is_ok());
    }
}
