//! The process-wide GPU context: instance, adapter, device and queue, made
//! once and shared by every case a process runs ([`GpuContext::get`]).
//!
//! - **Backends** come from `WGPU_BACKEND` (a comma list: `vulkan`, `metal`,
//!   `dx12`); default Vulkan + Metal + DX12. This build has no GL backend on
//!   purpose: with no Vulkan driver wgpu would otherwise fall back to GL on
//!   llvmpipe silently, with other limits and features.
//! - **Adapter**: `WGPU_ADAPTER_NAME` (a case-insensitive substring of the
//!   name) picks one; otherwise the first discrete, then integrated, virtual,
//!   CPU (lavapipe) adapter, in enumeration order within a type.
//! - **Limits**: the adapter's real limits are requested (wgpu's defaults
//!   allow only 8 storage buffers and 256 MiB bindings), and every dispatch
//!   and binding is checked against them ([`GpuContext::dispatch`],
//!   [`GpuContext::check_binding`]).
//! - **Pipeline cache**: where the adapter has `PIPELINE_CACHE` (Vulkan), one
//!   wgpu pipeline cache per process, loaded from and saved to
//!   `$HOTPATH_PIPELINE_CACHE` (default `<tmp>/hotpath-pipeline-cache/`), so
//!   the judge's worker processes do not recompile every kernel.
//!
//! No adapter is [`Error::NotSupported`] with how to get one.

use std::path::PathBuf;
use std::sync::OnceLock;

use serde::Serialize;

use crate::error::{Error, Result};

/// What `hpjudge info` and the scoreboard record about an adapter.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct AdapterSummary {
    pub name: String,
    /// `vulkan`, `metal`, `dx12`, ...
    pub backend: String,
    /// `discrete_gpu`, `integrated_gpu`, `virtual_gpu`, `cpu`, `other`.
    pub device_type: String,
    pub driver: String,
    pub driver_info: String,
    pub vendor: u32,
    pub device: u32,
}

impl AdapterSummary {
    fn of(info: &wgpu::AdapterInfo) -> Self {
        let device_type = match info.device_type {
            wgpu::DeviceType::DiscreteGpu => "discrete_gpu",
            wgpu::DeviceType::IntegratedGpu => "integrated_gpu",
            wgpu::DeviceType::VirtualGpu => "virtual_gpu",
            wgpu::DeviceType::Cpu => "cpu",
            wgpu::DeviceType::Other => "other",
        };
        AdapterSummary {
            name: info.name.clone(),
            backend: info.backend.to_str().to_string(),
            device_type: device_type.to_string(),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            vendor: info.vendor,
            device: info.device,
        }
    }
}

/// How to get an adapter, for the `NotSupported` message.
pub const HOW_TO_GET_ONE: &str = "install a Vulkan driver (Debian/Ubuntu without a GPU: \
     `apt-get install mesa-vulkan-drivers libvulkan1` gives the lavapipe software adapter), \
     or set WGPU_BACKEND to a backend this machine has";

/// The backend set: `WGPU_BACKEND` or Vulkan + Metal + DX12, never GL.
pub fn backends() -> Result<wgpu::Backends> {
    let default = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
    match std::env::var("WGPU_BACKEND") {
        Err(_) => Ok(default),
        Ok(s) => {
            let b = wgpu::Backends::from_comma_list(&s);
            if b.contains(wgpu::Backends::GL) {
                return Err(Error::NotSupported(format!(
                    "WGPU_BACKEND={s}: this build has no GL backend (use vulkan, metal or dx12)"
                )));
            }
            if b.is_empty() {
                return Err(Error::invalid(
                    "WGPU_BACKEND",
                    format!("{s:?} names no backend (vulkan, metal, dx12)"),
                ));
            }
            Ok(b)
        }
    }
}

fn instance(b: wgpu::Backends) -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = b;
    wgpu::Instance::new(desc)
}

/// Every adapter of the pinned backends (empty when there is none, or when
/// `WGPU_BACKEND` is unusable).
pub fn adapters() -> Vec<AdapterSummary> {
    let Ok(b) = backends() else { return vec![] };
    let inst = instance(b);
    pollster::block_on(inst.enumerate_adapters(b))
        .iter()
        .map(|a| AdapterSummary::of(&a.get_info()))
        .collect()
}

/// The GPU block of `hpjudge info --json` and of the scoreboard's
/// environment: every adapter of the pinned backends, the one the GPU cases
/// use (`selected`, null when none), whether its kernels may use `f64`
/// (`shader_f64`) and why none could be used (`error`).
pub fn describe() -> serde_json::Value {
    let (selected, f64s, error) = match GpuContext::get() {
        Ok(c) => (
            serde_json::to_value(c.summary()).ok(),
            Some(c.has_f64()),
            None,
        ),
        Err(e) => (None, None, Some(e.to_string())),
    };
    serde_json::json!({
        "backends": std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan,metal,dx12".into()),
        "adapters": adapters(),
        "selected": selected,
        "shader_f64": f64s,
        "error": error,
    })
}

fn type_rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

/// The shared device. Fields are public for the kernel families in
/// `src/gpu/`; everything else goes through the helpers.
pub struct GpuContext {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// The limits the device was created with (the adapter's own).
    pub limits: wgpu::Limits,
    info: wgpu::AdapterInfo,
    cache: Option<wgpu::PipelineCache>,
    cache_file: Option<PathBuf>,
}

static CONTEXT: OnceLock<std::result::Result<GpuContext, (bool, String)>> = OnceLock::new();

/// One dispatch of a 1-D kernel over `n` items with workgroup size `wg`,
/// laid out as a 2-D grid so any `n` up to the limits fits: the kernel's
/// linear index is `gid.x + gid.y * groups_x * wg` (see `common.wgsl`
/// `linear_id`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dispatch {
    pub groups_x: u32,
    pub groups_y: u32,
}

impl GpuContext {
    /// The process's context, created on first use.
    pub fn get() -> Result<&'static GpuContext> {
        match CONTEXT.get_or_init(|| {
            GpuContext::create().map_err(|e| (matches!(e, Error::NotSupported(_)), e.to_string()))
        }) {
            Ok(c) => Ok(c),
            Err((true, m)) => Err(Error::NotSupported(
                m.trim_start_matches("not supported: ").to_string(),
            )),
            Err((false, m)) => Err(Error::Gpu(m.clone())),
        }
    }

    fn create() -> Result<GpuContext> {
        let b = backends()?;
        let inst = instance(b);
        let mut all = pollster::block_on(inst.enumerate_adapters(b));
        if let Ok(want) = std::env::var("WGPU_ADAPTER_NAME") {
            let w = want.to_lowercase();
            all.retain(|a| a.get_info().name.to_lowercase().contains(&w));
            if all.is_empty() {
                let names: Vec<String> = adapters().into_iter().map(|a| a.name).collect();
                return Err(Error::NotSupported(format!(
                    "WGPU_ADAPTER_NAME={want} matches no adapter (have {names:?})"
                )));
            }
        }
        let adapter = all
            .into_iter()
            .enumerate()
            .min_by_key(|(i, a)| (type_rank(a.get_info().device_type), *i))
            .map(|(_, a)| a)
            .ok_or_else(|| {
                Error::NotSupported(format!(
                    "no GPU adapter for backends {b:?}: {HOW_TO_GET_ONE}"
                ))
            })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let features = adapter.features()
            & (wgpu::Features::PIPELINE_CACHE
                | wgpu::Features::TIMESTAMP_QUERY
                | wgpu::Features::SHADER_F64);
        let desc = wgpu::DeviceDescriptor {
            label: Some("hotpath"),
            required_features: features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).map_err(|e| {
            Error::Gpu(format!(
                "request_device on {} ({}): {e}",
                info.name,
                info.backend.to_str()
            ))
        })?;
        let (cache, cache_file) = if features.contains(wgpu::Features::PIPELINE_CACHE) {
            open_cache(&device, &info)
        } else {
            (None, None)
        };
        tracing::info!(adapter = %info.name, backend = info.backend.to_str(), driver = %info.driver, "GPU context");
        Ok(GpuContext {
            adapter,
            device,
            queue,
            limits,
            info,
            cache,
            cache_file,
        })
    }

    /// Name, backend and driver of the adapter in use.
    pub fn summary(&self) -> AdapterSummary {
        AdapterSummary::of(&self.info)
    }

    /// Whether launches can be timed on the GPU's own clock (the adapter has
    /// `TIMESTAMP_QUERY`; [`super::buffers::run_timed`] then reports `kernel_s`).
    pub fn has_timestamps(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Whether kernels may use `f64` (the adapter has `SHADER_F64`; the
    /// voxel beam pre-pass, `kernels/voxel_beam.wgsl`, needs it).
    pub fn has_f64(&self) -> bool {
        self.device.features().contains(wgpu::Features::SHADER_F64)
    }

    /// The pipeline cache, where the adapter supports one.
    pub fn pipeline_cache(&self) -> Option<&wgpu::PipelineCache> {
        self.cache.as_ref()
    }

    /// Writes the pipeline cache to disk (temp file + rename), best effort:
    /// a failure only costs compile time next run.
    pub fn save_pipeline_cache(&self) {
        let (Some(c), Some(path)) = (&self.cache, &self.cache_file) else {
            return;
        };
        let Some(data) = c.get_data() else { return };
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        if std::fs::write(&tmp, &data)
            .and_then(|_| std::fs::rename(&tmp, path))
            .is_err()
        {
            std::fs::remove_file(&tmp).ok();
            tracing::debug!(path = %path.display(), "pipeline cache not saved");
        }
    }

    /// Plans a 1-D dispatch of `n` items at workgroup size `wg` against
    /// this adapter's limits (see [`plan_dispatch`]).
    pub fn dispatch(&self, label: &str, n: u64, wg: u32) -> Result<Dispatch> {
        plan_dispatch(
            label,
            n,
            wg,
            self.limits.max_compute_workgroups_per_dimension,
        )
    }

    /// Refuses a storage binding of `bytes` over the adapter's
    /// `max_storage_buffer_binding_size` or `max_buffer_size`.
    pub fn check_binding(&self, label: &str, bytes: u64) -> Result<()> {
        let lim = self.max_binding();
        if bytes > lim {
            return Err(Error::NotSupported(format!(
                "{label}: a {bytes}-byte storage buffer is over this adapter's {lim}-byte binding limit \
                 (max_storage_buffer_binding_size / max_buffer_size); use a smaller batch or grid"
            )));
        }
        Ok(())
    }

    /// Loop iterations one shader invocation may run in total, where the
    /// driver caps it: Mesa's llvmpipe/lavapipe breaks out of every loop
    /// after 65535 iterations (gallivm `LP_MAX_TGSI_LOOP_ITERATIONS`,
    /// measured: a ray of 1e5 lattice points stopped at 13107 = 65535 / 5).
    /// `None` where no cap is known.
    pub fn max_loop_iterations(&self) -> Option<u64> {
        (self.info.driver == "llvmpipe" || self.info.name.starts_with("llvmpipe")).then_some(65_535)
    }

    /// The largest storage buffer one binding may hold, in bytes.
    pub fn max_binding(&self) -> u64 {
        self.limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size)
    }
}

/// Lays `n` items at workgroup size `wg` out as `groups_x * groups_y`
/// workgroups, each side at most `max` (the adapter's
/// `max_compute_workgroups_per_dimension`), or refuses a batch even a
/// `max x max` grid cannot hold. `n = 0` gives 0 groups (callers skip it).
pub fn plan_dispatch(label: &str, n: u64, wg: u32, max: u32) -> Result<Dispatch> {
    let max = max as u64;
    let groups = n.div_ceil(wg.max(1) as u64);
    if groups == 0 {
        return Ok(Dispatch {
            groups_x: 0,
            groups_y: 0,
        });
    }
    let gx = groups.min(max);
    let gy = groups.div_ceil(gx);
    if gy > max {
        return Err(Error::NotSupported(format!(
            "{label}: {n} items need {groups} workgroups of {wg}, over this adapter's {max} x {max} \
             (max_compute_workgroups_per_dimension); render in smaller batches"
        )));
    }
    Ok(Dispatch {
        groups_x: gx as u32,
        groups_y: gy as u32,
    })
}

fn open_cache(
    device: &wgpu::Device,
    info: &wgpu::AdapterInfo,
) -> (Option<wgpu::PipelineCache>, Option<PathBuf>) {
    let dir = std::env::var_os("HOTPATH_PIPELINE_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("hotpath-pipeline-cache"));
    let file = wgpu::util::pipeline_cache_key(info).map(|k| dir.join(k));
    let data = file.as_ref().and_then(|f| std::fs::read(f).ok());
    // SAFETY: the data was written by `save_pipeline_cache` for the same
    // adapter key (vendor, device, driver); `fallback: true` makes wgpu and
    // the driver discard data they do not recognise.
    let cache = unsafe {
        device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
            label: Some("hotpath"),
            data: data.as_deref(),
            fallback: true,
        })
    };
    if let Some(f) = &file {
        std::fs::create_dir_all(&dir).ok();
        tracing::debug!(path = %f.display(), loaded = data.is_some(), "pipeline cache");
    }
    (Some(cache), file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatch_plans_cover_every_item_within_limits() {
        for (n, wg, max) in [
            (1u64, 64u32, 65535u32),
            (64, 64, 65535),
            (65, 64, 65535),
            (1 << 30, 64, 65535),
            (1000, 8, 4),
        ] {
            match plan_dispatch("t", n, wg, max) {
                Ok(d) => {
                    assert!(d.groups_x <= max && d.groups_y <= max);
                    let cap = d.groups_x as u64 * d.groups_y as u64 * wg as u64;
                    assert!(
                        cap >= n && cap < n + d.groups_x as u64 * wg as u64,
                        "{n} {d:?}"
                    );
                }
                Err(e) => assert!((1000, 8, 4) == (n, wg, max), "{e}"),
            }
        }
        let e = plan_dispatch("f_fused", 1000, 8, 4)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("f_fused") && e.contains("smaller batches"),
            "{e}"
        );
        assert_eq!(
            plan_dispatch("t", 0, 64, 8).unwrap(),
            Dispatch {
                groups_x: 0,
                groups_y: 0
            }
        );
    }

    #[test]
    fn describe_names_the_selected_adapter_among_the_adapters() {
        let d = describe();
        eprintln!("{d}");
        let adapters = d["adapters"].as_array().unwrap();
        if d["selected"].is_null() {
            assert!(
                d["error"].as_str().unwrap().contains("mesa-vulkan-drivers")
                    || !adapters.is_empty()
            );
        } else {
            assert!(adapters.contains(&d["selected"]), "{d}");
        }
    }
}
