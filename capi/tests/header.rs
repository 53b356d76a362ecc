//! `include/hotpath.h` checked against the Rust declarations:
//! - it is ASCII and compiles alone with `cc -std=c99 -Wall -Werror -pedantic`;
//! - every struct's size and every field's offset, compiled by C, equal the
//!   `#[repr(C)]` mirrors in `src/abi.rs`;
//! - its `#define HP_*` set and values equal `abi::DEFINES`;
//! - its prototypes name exactly the crate's `extern "C"` functions, with the
//!   same parameter and return types.

use std::collections::BTreeMap;
use std::mem::{offset_of, size_of};
use std::path::{Path, PathBuf};
use std::process::Command;

use hotpath_capi::abi::*;

fn header_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../include/hotpath.h")
}

fn header() -> String {
    std::fs::read_to_string(header_path()).expect("include/hotpath.h")
}

fn work() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let d = exe
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .join("capi-tests/header");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Compiles and runs a C program; returns its stdout.
fn run_c(name: &str, src: &str) -> String {
    let dir = work();
    let c = dir.join(format!("{name}.c"));
    let exe = dir.join(name);
    std::fs::write(&c, src).unwrap();
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let out = Command::new(cc)
        .args(["-std=c99", "-Wall", "-Werror", "-pedantic", "-I"])
        .arg(header_path().parent().unwrap())
        .arg(&c)
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("a C compiler (cc)");
    assert!(
        out.status.success(),
        "cc failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(&exe).output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn header_is_ascii_and_compiles_alone() {
    let h = header();
    assert!(h.is_ascii(), "include/hotpath.h has non-ASCII bytes");
    let out = run_c(
        "alone",
        "#include \"hotpath.h\"\nint main(void) { return 0; }\n",
    );
    assert!(out.is_empty());
}

macro_rules! layout {
    ($c:literal, $t:ty, [$($f:ident),*]) => {
        (
            $c,
            size_of::<$t>(),
            vec![$((stringify!($f), offset_of!($t, $f))),*],
        )
    };
}

#[test]
fn struct_layouts_match_the_rust_mirrors() {
    let structs = vec![
        layout!("hp_header", HpHeader, [abi_version, reserved, caps]),
        layout!(
            "hp_tensor",
            HpTensor,
            [data, dtype, memspace, ndim, reserved, shape, stride]
        ),
        layout!(
            "hp_camera",
            HpCamera,
            [
                kind,
                width,
                height,
                reserved,
                fx,
                fy,
                cx,
                cy,
                half_width,
                half_height,
                c2w
            ]
        ),
        layout!(
            "hp_plan_desc",
            HpPlanDesc,
            [
                next, backend, precision, camera, aabb_min, aabb_max, near_t, far_t, dt,
                early_stop, background, max_steps, sampling, seed, trans_path
            ]
        ),
        layout!("hp_rays_t", HpRays, [next, count, o, d, t0, t1, pixel]),
        layout!(
            "hp_samp_t",
            HpSamp,
            [next, capacity, count, off, flags, ray_id, t, dt, sigma, color]
        ),
        layout!(
            "hp_intl_t",
            HpIntl,
            [next, rgb, trans, logtrans, depth, opacity, nsamples, flags, alpha, log_t]
        ),
        layout!(
            "hp_img_t",
            HpImg,
            [next, rgb, trans, logtrans, depth, opacity, hit, nsamples]
        ),
        layout!(
            "hp_grads_t",
            HpGrads,
            [next, fs, fc, rays, dsigma, dcolor, dcam]
        ),
    ];
    let mut src = String::from(
        "#include <stdio.h>\n#include <stddef.h>\n#include \"hotpath.h\"\nint main(void) {\n",
    );
    let mut want = String::new();
    for (name, size, fields) in &structs {
        src += &format!("    printf(\"{name} %lu\\n\", (unsigned long)sizeof({name}));\n");
        want += &format!("{name} {size}\n");
        for (f, off) in fields {
            src += &format!(
                "    printf(\"{name}.{f} %lu\\n\", (unsigned long)offsetof({name}, {f}));\n"
            );
            want += &format!("{name}.{f} {off}\n");
        }
    }
    src += "    return 0;\n}\n";
    assert_eq!(run_c("layout", &src), want);
    // Every struct of the header is in the list above (a new one needs a mirror).
    let h = header();
    let declared: Vec<&str> = h
        .lines()
        .filter_map(|l| l.strip_prefix("typedef struct "))
        .filter(|l| l.ends_with('{'))
        .map(|l| l.trim_end_matches('{').trim())
        .collect();
    let mirrored: Vec<&str> = structs.iter().map(|s| s.0).collect();
    assert_eq!(declared, mirrored);
}

#[test]
fn defines_match_the_rust_constants() {
    let h = header();
    let in_header: Vec<&str> = h
        .lines()
        .filter_map(|l| l.strip_prefix("#define HP_"))
        .map(|l| l.split_whitespace().next().unwrap())
        .collect();
    let names: Vec<String> = DEFINES.iter().map(|d| d.0.to_string()).collect();
    let in_header: Vec<String> = in_header.iter().map(|n| format!("HP_{n}")).collect();
    assert_eq!(
        in_header, names,
        "header #defines vs abi::DEFINES (same order)"
    );
    let mut src = String::from("#include <stdio.h>\n#include \"hotpath.h\"\nint main(void) {\n");
    let mut want = String::new();
    for (n, v) in DEFINES {
        src += &format!("    printf(\"{n} %llu\\n\", (unsigned long long)({n}));\n");
        want += &format!("{n} {v}\n");
    }
    src += "    return 0;\n}\n";
    assert_eq!(run_c("defines", &src), want);
}

/// C spelling of a Rust FFI type.
fn c_type(rust: &str) -> String {
    let t = rust.trim();
    if let Some(rest) = t.strip_prefix("*const ") {
        return format!("const {}*", c_type(rest)).replace("const const", "const");
    }
    if let Some(rest) = t.strip_prefix("*mut ") {
        return format!("{}*", c_type(rest));
    }
    let base = t.rsplit("::").next().unwrap();
    match base {
        "i32" => "hp_status".into(),
        "u32" => "uint32_t".into(),
        "u64" => "uint64_t".into(),
        "usize" => "size_t".into(),
        "f64" => "double".into(),
        "c_char" => "char".into(),
        "c_void" => "void".into(),
        "HpCtx" => "hp_ctx".into(),
        "HpPlan" => "hp_plan".into(),
        "HpField" => "hp_field".into(),
        "HpHeader" => "hp_header".into(),
        "HpTensor" => "hp_tensor".into(),
        "HpCamera" => "hp_camera".into(),
        "HpPlanDesc" => "hp_plan_desc".into(),
        "HpRays" => "hp_rays_t".into(),
        "HpSamp" => "hp_samp_t".into(),
        "HpIntl" => "hp_intl_t".into(),
        "HpImg" => "hp_img_t".into(),
        "HpGrads" => "hp_grads_t".into(),
        other => panic!("no C spelling for Rust type {other}"),
    }
}

/// Normalises a C parameter: drops the name, turns `T name[N]` into `T*`.
fn c_param(p: &str) -> String {
    let p = p.trim();
    if p == "void" {
        return String::new();
    }
    let (decl, array) = match p.find('[') {
        Some(i) => (&p[..i], true),
        None => (p, false),
    };
    let decl = decl.trim();
    let cut = decl.rfind([' ', '*']).expect("a parameter name");
    let ty = decl[..=cut].replace(' ', "");
    let ty = ty.replace("const", "const ");
    if array {
        format!("{}*", ty.trim())
    } else {
        ty.trim().to_string()
    }
}

fn header_prototypes() -> BTreeMap<String, (String, Vec<String>)> {
    let h = header();
    let mut out = BTreeMap::new();
    for l in h.lines() {
        let l = l.trim();
        if !(l.ends_with(");") && l.contains("hp_") && l.contains('(')) || l.starts_with('#') {
            continue;
        }
        let open = l.find('(').unwrap();
        let head = &l[..open];
        let cut = head.rfind([' ', '*']).unwrap();
        let name = head[cut + 1..].trim().to_string();
        let ret = head[..=cut].replace(' ', "").replace("const", "const ");
        let args = &l[open + 1..l.len() - 2];
        let params: Vec<String> = args
            .split(',')
            .map(c_param)
            .filter(|p| !p.is_empty())
            .map(|p| p.replace(' ', ""))
            .collect();
        out.insert(name, (ret.replace(' ', ""), params));
    }
    out
}

fn rust_prototypes() -> BTreeMap<String, (String, Vec<String>)> {
    let srcs = [
        include_str!("../src/plan.rs"),
        include_str!("../src/field.rs"),
        include_str!("../src/stages.rs"),
    ];
    let mut out = BTreeMap::new();
    for src in srcs {
        let mut rest = src;
        while let Some(i) = rest.find("extern \"C\" fn ") {
            let after = &rest[i + "extern \"C\" fn ".len()..];
            let open = after.find('(').unwrap();
            let name = after[..open].trim().to_string();
            let close = after.find(") ->").expect("extern fns return a value");
            let params: Vec<String> = after[open + 1..close]
                .split(',')
                .map(str::trim)
                .filter(|p| !p.is_empty())
                .map(|p| c_type(p.split_once(':').unwrap().1).replace(' ', ""))
                .collect();
            let ret_end = after[close..].find('{').unwrap() + close;
            let ret = c_type(&after[close + 4..ret_end]).replace(' ', "");
            out.insert(name, (ret, params));
            rest = &after[ret_end..];
        }
    }
    out
}

#[test]
fn prototypes_match_the_extern_c_functions() {
    let h = header_prototypes();
    let r = rust_prototypes();
    assert_eq!(
        h.keys().collect::<Vec<_>>(),
        r.keys().collect::<Vec<_>>(),
        "functions in the header vs extern \"C\" functions"
    );
    for (name, sig) in &h {
        assert_eq!(sig, &r[name], "{name}: header vs Rust");
    }
    assert!(h.len() >= 20, "{} prototypes parsed", h.len());
}
