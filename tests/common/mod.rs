//! What the integration tests share: the binary under test, a fresh temp
//! folder per test, and the `hpjudge run MANIFEST --out OUT` spawn.

#![allow(dead_code)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test; `HPJUDGE_IT_BIN` points these tests at another
/// build (how a fix is shown to make a test pass that failed before it).
pub fn exe() -> PathBuf {
    std::env::var_os("HPJUDGE_IT_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_hpjudge")))
}

/// `hpjudge` in the project root, `CI` unset.
pub fn hpjudge() -> Command {
    let mut c = Command::new(exe());
    c.current_dir(env!("CARGO_MANIFEST_DIR")).env_remove("CI");
    c
}

/// A test's temp folder: removed when the test passes, kept (and named
/// in the failure's output by the test's own messages) when it panics.
pub struct TmpDir(PathBuf);

impl std::ops::Deref for TmpDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TmpDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<OsStr> for TmpDir {
    fn as_ref(&self) -> &OsStr {
        self.0.as_os_str()
    }
}

impl Drop for TmpDir {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// An empty folder `hpjudge-<suite>-<pid>-<name>-<k>` under the temp
/// folder, `k` counting the calls (tests run in parallel threads, and some
/// helpers ask for the same name).
pub fn tmp_in(suite: &str, name: &str) -> TmpDir {
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let k = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let pid = std::process::id();
    let d = std::env::temp_dir().join(format!("hpjudge-{suite}-{pid}-{name}-{k}"));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    TmpDir(d)
}

/// stdout then stderr.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `hpjudge run MANIFEST --out OUT EXTRA...`, not started.
pub fn run_cmd(manifest: impl AsRef<OsStr>, out: &Path, extra: &[&str]) -> Command {
    let mut c = hpjudge();
    c.arg("run").arg(manifest).arg("--out").arg(out).args(extra);
    c
}

/// `hpjudge run MANIFEST --out OUT EXTRA...`, run to its end.
pub fn run_out(manifest: impl AsRef<OsStr>, out: &Path, extra: &[&str]) -> Output {
    run_cmd(manifest, out, extra).output().unwrap()
}
