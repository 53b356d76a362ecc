//! Buffers, launches and the one readback helper.
//!
//! A launch is a list of [`Pass`]es (pipeline, bindings of group 0 in
//! binding order, item count) encoded into ONE command buffer, followed by
//! copies of the buffers to read into MAP_READ staging buffers, one submit,
//! one wait, then the bytes come back ([`run`]). Every binding and dispatch
//! is checked against the adapter's limits before anything is encoded.

use std::time::Instant;

use bytemuck::Pod;
use wgpu::util::DeviceExt;

use super::context::GpuContext;
use crate::error::{Error, Result};

/// Smallest buffer made (wgpu refuses zero-sized bindings).
const MIN_BYTES: u64 = 16;

/// A read-only storage buffer holding `data` (at least [`MIN_BYTES`]).
pub fn storage_in<T: Pod>(ctx: &GpuContext, label: &str, data: &[T]) -> Result<wgpu::Buffer> {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    ctx.check_binding(label, bytes.len() as u64)?;
    let padded;
    let contents = if (bytes.len() as u64) < MIN_BYTES {
        padded = [
            bytes,
            &[0u8; MIN_BYTES as usize][..MIN_BYTES as usize - bytes.len()],
        ]
        .concat();
        &padded[..]
    } else {
        bytes
    };
    Ok(ctx
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        }))
}

/// A writable storage buffer of `bytes` (rounded up to 4, at least
/// [`MIN_BYTES`]) that can be read back.
pub fn storage_out(ctx: &GpuContext, label: &str, bytes: u64) -> Result<wgpu::Buffer> {
    ctx.check_binding(label, bytes)?;
    Ok(ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.next_multiple_of(4).max(MIN_BYTES),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    }))
}

/// A uniform buffer holding one `#[repr(C)]` parameter struct.
pub fn uniform<T: Pod>(ctx: &GpuContext, label: &str, value: &T) -> wgpu::Buffer {
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM,
        })
}

/// One compute dispatch: `pipeline` over `n` items (workgroup size `wg`),
/// with `(binding, buffer)` pairs of `@group(0)` (exactly the bindings the
/// entry point uses: wgpu derives the layout from the shader).
#[derive(Clone, Copy)]
pub struct Pass<'a> {
    pub label: &'a str,
    pub pipeline: &'a wgpu::ComputePipeline,
    pub buffers: &'a [(u32, &'a wgpu::Buffer)],
    pub n: u64,
    pub wg: u32,
}

/// Bind group 0 of `pipeline` (layout derived from the shader) with
/// `(binding, buffer)` pairs.
pub fn bind_group(
    ctx: &GpuContext,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: *i,
            resource: b.as_entire_binding(),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Bytes read back, one vector per buffer asked for, the seconds from
/// submit to the end of the readback copies (kernels + copies, without
/// pipeline builds or uploads), and, for [`run_timed`] where the adapter
/// has timestamp queries, the seconds on the GPU's clock from the start of
/// the first pass to the end of the last (the kernels alone).
pub struct Readback {
    pub bytes: Vec<Vec<u8>>,
    pub gpu_s: f64,
    pub kernel_s: Option<f64>,
}

impl Readback {
    /// Buffer `i` as a vector of `T`, truncated to `n` elements.
    pub fn take<T: Pod>(&self, i: usize, n: usize) -> Result<Vec<T>> {
        let b = self
            .bytes
            .get(i)
            .ok_or_else(|| Error::Gpu(format!("readback has no buffer {i}")))?;
        let mut v: Vec<T> = bytemuck::pod_collect_to_vec(b);
        if v.len() < n {
            return Err(Error::Gpu(format!(
                "readback buffer {i} has {} elements, {n} expected",
                v.len()
            )));
        }
        v.truncate(n);
        Ok(v)
    }
}

/// Encodes `passes` in order into one command buffer, copies every buffer
/// of `read` to a staging buffer, submits once and waits; returns their
/// bytes. Validation and out-of-memory errors become [`Error::Gpu`] naming
/// `label`.
pub fn run(
    ctx: &GpuContext,
    label: &str,
    passes: &[Pass],
    read: &[&wgpu::Buffer],
) -> Result<Readback> {
    launch(ctx, label, passes, read, false)
}

/// [`run`], also timing the passes on the GPU's clock where the adapter has
/// timestamp queries (`Readback::kernel_s`; a query set and two small
/// buffers more per launch, so only the launches that report it ask).
pub fn run_timed(
    ctx: &GpuContext,
    label: &str,
    passes: &[Pass],
    read: &[&wgpu::Buffer],
) -> Result<Readback> {
    launch(ctx, label, passes, read, true)
}

fn launch(
    ctx: &GpuContext,
    label: &str,
    passes: &[Pass],
    read: &[&wgpu::Buffer],
    timed: bool,
) -> Result<Readback> {
    let dev = &ctx.device;
    let plans = passes
        .iter()
        .map(|p| ctx.dispatch(p.label, p.n, p.wg))
        .collect::<Result<Vec<_>>>()?;
    let oom = dev.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let val = dev.push_error_scope(wgpu::ErrorFilter::Validation);
    let mut enc =
        dev.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
    let live: Vec<usize> = (0..passes.len())
        .filter(|&i| plans[i].groups_x != 0)
        .collect();
    let clock = (timed && ctx.has_timestamps() && !live.is_empty()).then(|| Clock::new(ctx));
    for (i, (p, plan)) in passes.iter().zip(&plans).enumerate() {
        if plan.groups_x == 0 {
            continue;
        }
        let bg = bind_group(ctx, p.label, p.pipeline, p.buffers);
        // Only the first and the last live pass are timed (wgpu refuses
        // timestamp writes with neither index set).
        let (first, last) = (Some(&i) == live.first(), Some(&i) == live.last());
        let timestamp_writes =
            clock
                .as_ref()
                .filter(|_| first || last)
                .map(|c| wgpu::ComputePassTimestampWrites {
                    query_set: &c.queries,
                    beginning_of_pass_write_index: first.then_some(0),
                    end_of_pass_write_index: last.then_some(1),
                });
        let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(p.label),
            timestamp_writes,
        });
        cp.set_pipeline(p.pipeline);
        cp.set_bind_group(0, &bg, &[]);
        cp.dispatch_workgroups(plan.groups_x, plan.groups_y, 1);
    }
    let staging: Vec<wgpu::Buffer> = read
        .iter()
        .map(|b| {
            let s = dev.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: b.size(),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_buffer_to_buffer(b, 0, &s, 0, b.size());
            s
        })
        .collect();
    if let Some(c) = &clock {
        c.resolve(&mut enc);
    }
    let t = Instant::now();
    ctx.queue.submit([enc.finish()]);
    for s in staging.iter().chain(clock.as_ref().map(|c| &c.staging)) {
        s.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    }
    dev.poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| Error::Gpu(format!("{label}: waiting for the GPU: {e}")))?;
    let gpu_s = t.elapsed().as_secs_f64();
    if let Some(e) = pollster::block_on(val.pop()) {
        return Err(Error::Gpu(format!("{label}: {e}")));
    }
    if let Some(e) = pollster::block_on(oom.pop()) {
        return Err(Error::Gpu(format!("{label}: out of GPU memory: {e}")));
    }
    let mut bytes = Vec::with_capacity(staging.len());
    for s in &staging {
        let view = s
            .slice(..)
            .get_mapped_range()
            .map_err(|e| Error::Gpu(format!("{label}: mapping a readback buffer: {e}")))?;
        bytes.push(view.to_vec());
        drop(view);
        s.unmap();
    }
    let kernel_s = match &clock {
        Some(c) => Some(c.seconds(ctx, label)?),
        None => None,
    };
    Ok(Readback {
        bytes,
        gpu_s,
        kernel_s,
    })
}

/// Two GPU timestamps (start of a launch's first pass, end of its last),
/// resolved into a buffer and copied to a mappable one.
struct Clock {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    staging: wgpu::Buffer,
}

impl Clock {
    fn new(ctx: &GpuContext) -> Clock {
        let dev = &ctx.device;
        let buffer = |label, usage| {
            dev.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 2 * wgpu::QUERY_SIZE as u64,
                usage,
                mapped_at_creation: false,
            })
        };
        Clock {
            queries: dev.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("launch clock"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            }),
            resolved: buffer(
                "launch clock resolved",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            ),
            staging: buffer(
                "launch clock readback",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
        }
    }

    fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        enc.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        enc.copy_buffer_to_buffer(&self.resolved, 0, &self.staging, 0, self.resolved.size());
    }

    /// Seconds between the two timestamps (after the submit's wait).
    fn seconds(&self, ctx: &GpuContext, label: &str) -> Result<f64> {
        let view = self
            .staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| Error::Gpu(format!("{label}: mapping the launch clock: {e}")))?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&view);
        drop(view);
        self.staging.unmap();
        let period_ns = ctx.queue.get_timestamp_period() as f64;
        Ok(ticks[1].wrapping_sub(ticks[0]) as f64 * period_ns * 1e-9)
    }
}
