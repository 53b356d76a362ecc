//! The C ABI used from C and from Python, compared with `hpjudge render`.
//!
//! `c_program_matches_hpjudge_render`: compiles `tests/c/hp_test.c` with the
//! system C compiler (`-std=c99 -Wall -Werror -pedantic`) against
//! `include/hotpath.h` and `libhotpath_capi.so`; the program writes its
//! inputs (a density grid, a colour grid, dL/dI), `hpjudge render` renders
//! `vol_gaussian` (f32 and f64) and a scene of those grids with
//! `--grad-from`, and the program renders the same through `hp_ray` ->
//! `hp_samp` -> `hp_int` -> `hp_img` and `hp_diff` and compares every output
//! bit for bit, then runs its misuse cases.
//!
//! `python_example_matches_hpjudge_render`: `examples/python/hp_render.py`
//! (ctypes + numpy) renders `vol_gaussian` and must reproduce hpjudge's
//! image exactly; skipped with a message where python3 has no numpy
//! (scripts/test.sh installs it, so CI runs it).
//!
//! Both need `hpjudge` built in the same target folder
//! (`cargo build --release --bin hpjudge`; `cargo test --workspace` and
//! scripts/test.sh build it).

use std::path::{Path, PathBuf};
use std::process::Command;

/// target/<profile>, where cargo puts hpjudge and libhotpath_capi.so.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    exe.parent()
        .and_then(|d| d.parent())
        .expect("target/<profile>/deps/<test>")
        .to_path_buf()
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn hpjudge() -> PathBuf {
    let p = target_dir().join("hpjudge");
    assert!(
        p.is_file(),
        "{} not built: run `cargo build --release --bin hpjudge` (or cargo test --workspace)",
        p.display()
    );
    p
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{text}",
        out.status
    );
    text
}

/// A fresh work folder for one test.
fn work(name: &str) -> PathBuf {
    let d = target_dir().join("capi-tests").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A copy of the library this test was built with, in `dir/lib`. `cargo
/// test` refreshes the cdylib under deps/ only (target/<profile>/ holds the
/// one of the last `cargo build`), and sets LD_LIBRARY_PATH with both, so the
/// programs get this copy by path and rpath, with LD_LIBRARY_PATH removed.
fn fresh_lib(dir: &Path) -> PathBuf {
    let src = target_dir().join("deps/libhotpath_capi.so");
    assert!(src.is_file(), "{} missing", src.display());
    let lib = dir.join("lib");
    std::fs::create_dir_all(&lib).unwrap();
    std::fs::copy(&src, lib.join("libhotpath_capi.so")).unwrap();
    lib
}

fn render(scene: &Path, out: &Path, extra: &[&str]) {
    let mut c = Command::new(hpjudge());
    c.arg("render").arg(scene).arg("--out").arg(out).args(extra);
    run(&mut c);
}

#[test]
fn c_program_matches_hpjudge_render() {
    let dir = work("c");
    let root = root();
    let lib = fresh_lib(&dir);
    let exe = dir.join("hp_test");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    run(Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Werror", "-pedantic", "-O1"])
        .arg("-I")
        .arg(root.join("include"))
        .arg(root.join("capi/tests/c/hp_test.c"))
        .arg("-L")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .args(["-lhotpath_capi", "-lm", "-o"])
        .arg(&exe));
    run(Command::new(&exe)
        .env_remove("LD_LIBRARY_PATH")
        .arg("gen")
        .arg(&dir));

    let gauss = root.join("TESTS/scenes/vol_gaussian.yaml");
    render(&gauss, &dir.join("ref_gauss_f32"), &[]);
    render(&gauss, &dir.join("ref_gauss_f64"), &["--precision", "f64"]);
    let scene = dir.join("grid_scene.yaml");
    std::fs::write(
        &scene,
        "# hp_test.c's grid scene: its grid.npy / color.npy, camera as vol_gaussian.\n\
         renderer: volume\n\
         camera: {type: pinhole, position: [0, 0, 3], target: [0, 0, 0], up: [0, 1, 0], fov_y: 40}\n\
         width: 48\n\
         height: 40\n\
         field: {type: grid, file: grid.npy, oob: zero}\n\
         color: {type: grid, file: color.npy, oob: zero}\n",
    )
    .unwrap();
    let w = dir.join("w.npy");
    render(
        &scene,
        &dir.join("ref_grid"),
        &["--grad-from", w.to_str().unwrap()],
    );

    let out = run(Command::new(&exe)
        .env_remove("LD_LIBRARY_PATH")
        .arg("check")
        .arg(&dir));
    println!("{out}");
    assert!(out.contains("all C ABI checks passed"));
}

fn has_numpy() -> bool {
    Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn python_example_matches_hpjudge_render() {
    if !has_numpy() {
        eprintln!("SKIP python_example_matches_hpjudge_render: python3 with numpy not found");
        return;
    }
    let dir = work("python");
    let root = root();
    render(
        &root.join("TESTS/scenes/vol_gaussian.yaml"),
        &dir.join("ref"),
        &[],
    );
    let out = run(Command::new("python3")
        .env_remove("LD_LIBRARY_PATH")
        .arg(root.join("examples/python/hp_render.py"))
        .arg("--lib")
        .arg(fresh_lib(&dir).join("libhotpath_capi.so"))
        .arg("--compare")
        .arg(dir.join("ref/rgb.npy"))
        .arg("--out")
        .arg(dir.join("rgb.npy")));
    println!("{out}");
    assert!(out.contains("bit-identical"), "{out}");
}
