//! The kernel registry: every `kernels/*.wgsl` file, loaded with
//! `include_str!` and `kernels/common.wgsl` prepended (and, for a kernel
//! that extends another, that kernel's source, recursively: `hash_mlp`
//! reads the forward's fields and buffers from `volume`, `volume_diff`
//! extends `hash_mlp`), compiled once per process
//! into compute pipelines (memoised by kernel and entry point).
//!
//! A unit test validates every file in `kernels/` with naga, listing the
//! directory so a new file cannot be left out of [`KERNELS`].

use std::collections::HashMap;
use std::sync::Mutex;

use super::context::GpuContext;
use crate::error::{Error, Result};

/// `kernels/common.wgsl`, prepended to every kernel.
pub const COMMON: &str = include_str!("../../kernels/common.wgsl");

/// One kernel file: its name (file stem), its own text (without common),
/// the kernel it extends (prepended after common), if any, and whether it
/// uses `f64` (built only where the adapter has `SHADER_F64`).
#[derive(Clone, Copy, Debug)]
pub struct Kernel {
    pub name: &'static str,
    pub text: &'static str,
    pub base: Option<&'static str>,
    pub f64: bool,
}

macro_rules! kernel {
    ($name:literal) => {
        Kernel {
            name: $name,
            text: include_str!(concat!("../../kernels/", $name, ".wgsl")),
            base: None,
            f64: false,
        }
    };
    ($name:literal extends $base:literal) => {
        Kernel {
            base: Some($base),
            ..kernel!($name)
        }
    };
    ($name:literal extends $base:literal with f64) => {
        Kernel {
            f64: true,
            ..kernel!($name extends $base)
        }
    };
}

/// Every kernel file except `common.wgsl`.
pub const KERNELS: &[Kernel] = &[
    kernel!("rays"),
    kernel!("rng"),
    kernel!("expm1"),
    kernel!("volume"),
    kernel!("hash_mlp" extends "volume"),
    kernel!("volume_diff" extends "hash_mlp"),
    kernel!("voxels"),
    kernel!("voxel_beam" extends "voxels" with f64),
    kernel!("voxel_attrs"),
    kernel!("transport"),
    kernel!("pathtrace"),
];

fn find(name: &str) -> Result<&'static Kernel> {
    KERNELS.iter().find(|k| k.name == name).ok_or_else(|| {
        Error::invalid(
            "kernel",
            format!("no kernel {name:?} in kernels/ (src/gpu/kernels.rs KERNELS)"),
        )
    })
}

/// The full source of kernel `name`: common.wgsl, the chain of kernels it
/// extends (the furthest first), then the file.
pub fn source(name: &str) -> Result<String> {
    Ok(format!("{COMMON}\n{}", own_chain(name, 0)?))
}

/// The texts of `name` and the kernels it extends, the furthest first.
fn own_chain(name: &str, depth: usize) -> Result<String> {
    let k = find(name)?;
    if depth > KERNELS.len() {
        return Err(Error::invalid("kernel", format!("{name:?} extends itself")));
    }
    let base = match k.base {
        Some(b) => format!("{}\n", own_chain(b, depth + 1)?),
        None => String::new(),
    };
    Ok(format!(
        "{base}// ---- kernels/{}.wgsl ----\n{}",
        k.name, k.text
    ))
}

/// Kernel, entry point, and its override constants (`name=value;` each).
type Key = (&'static str, &'static str, String);

static PIPELINES: Mutex<Option<HashMap<Key, wgpu::ComputePipeline>>> = Mutex::new(None);

/// The compute pipeline of `entry` in kernel `name`, built on first use
/// (with the context's pipeline cache) and shared after. Bind group 0 uses
/// the layout wgpu derives from the shader.
pub fn pipeline(
    ctx: &GpuContext,
    name: &'static str,
    entry: &'static str,
) -> Result<wgpu::ComputePipeline> {
    pipeline_with(ctx, name, entry, &[])
}

/// [`pipeline`] specialised by WGSL `override` constants (one pipeline per
/// distinct set of values): the driver sees constant branches and drops
/// the code they skip.
pub fn pipeline_with(
    ctx: &GpuContext,
    name: &'static str,
    entry: &'static str,
    constants: &[(&str, f64)],
) -> Result<wgpu::ComputePipeline> {
    let spec: String = constants.iter().map(|(k, v)| format!("{k}={v};")).collect();
    let mut guard = PIPELINES
        .lock()
        .map_err(|_| Error::Gpu("pipeline table poisoned by an earlier panic".into()))?;
    let table = guard.get_or_insert_with(HashMap::new);
    let key = (name, entry, spec);
    if let Some(p) = table.get(&key) {
        return Ok(p.clone());
    }
    if find(name)?.f64 && !ctx.has_f64() {
        return Err(Error::NotSupported(format!(
            "kernels/{name}.wgsl uses f64: the adapter has no SHADER_F64"
        )));
    }
    let src = source(name)?;
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = ctx
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(src.into()),
        });
    let p = ctx
        .device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants,
                ..Default::default()
            },
            cache: ctx.pipeline_cache(),
        });
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(Error::Gpu(format!(
            "kernels/{name}.wgsl entry {entry}: {e}"
        )));
    }
    ctx.save_pipeline_cache();
    table.insert(key, p.clone());
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses and validates `src` with naga (all capabilities wgpu may
    /// grant are not assumed: the default set, what every adapter has, and
    /// `FLOAT64` for a kernel marked `f64`).
    fn validate(name: &str, src: &str, f64: bool) {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        let mut caps = naga::valid::Capabilities::default();
        caps.set(naga::valid::Capabilities::FLOAT64, f64);
        let mut v = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps);
        if let Err(e) = v.validate(&module) {
            panic!("{name}: {}", e.emit_to_string(src));
        }
    }

    #[test]
    fn every_kernel_file_is_registered_and_valid_wgsl() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("kernels");
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        files.sort();
        assert!(files.iter().any(|f| f == "common.wgsl"), "{files:?}");
        for f in &files {
            let stem = f
                .strip_suffix(".wgsl")
                .unwrap_or_else(|| panic!("kernels/{f} is not a .wgsl file"));
            if stem == "common" {
                validate("common.wgsl", COMMON, false);
                continue;
            }
            let k = KERNELS.iter().find(|k| k.name == stem);
            assert!(
                k.is_some(),
                "kernels/{f} is not in src/gpu/kernels.rs KERNELS"
            );
            // The registered text is the file on disk (include_str! of it).
            assert_eq!(
                k.unwrap().text,
                std::fs::read_to_string(dir.join(f)).unwrap()
            );
            validate(f, &source(stem).unwrap(), k.unwrap().f64);
        }
        assert_eq!(
            files.len(),
            KERNELS.len() + 1,
            "a registered kernel has no file: {files:?}"
        );
    }

    #[test]
    fn kernel_headers_name_their_twin_and_parity_case() {
        for k in KERNELS {
            let head: String = k
                .text
                .lines()
                .take_while(|l| l.starts_with("//"))
                .collect::<Vec<_>>()
                .join("\n");
            assert!(
                head.contains("CPU twin:"),
                "kernels/{}.wgsl header names no CPU twin",
                k.name
            );
            assert!(
                head.contains("Parity case"),
                "kernels/{}.wgsl header names no parity case",
                k.name
            );
        }
    }

    #[test]
    fn unknown_kernels_are_refused_by_name() {
        let e = source("nope").unwrap_err().to_string();
        assert!(e.contains("nope"), "{e}");
    }
}
