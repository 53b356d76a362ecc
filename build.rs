//! Records the git revision for `hpjudge --version` and the scoreboard.
use std::process::Command;

fn main() {
    let rev = Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    let dirty = Command::new("git")
        .args(["status", "--porcelain", "--untracked-files=no"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .is_some_and(|o| !o.stdout.is_empty());
    let rev = rev.map(|r| format!("{r}{}", if dirty { "-dirty" } else { "" }));
    if let Some(r) = &rev {
        println!("cargo:rustc-env=HOTPATH_GIT_REVISION={r}");
    }
    let version = std::env::var("CARGO_PKG_VERSION").unwrap_or_default();
    println!(
        "cargo:rustc-env=HOTPATH_VERSION_LINE={version} ({})",
        rev.as_deref().unwrap_or("unknown")
    );
    println!("cargo:rerun-if-changed=.git/HEAD");
    println!("cargo:rerun-if-changed=.git/index");
}
