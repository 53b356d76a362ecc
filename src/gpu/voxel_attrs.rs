//! Host side of `kernels/voxel_attrs.wgsl`: a scene's per-leaf attributes
//! (plain and DXT, [`Attributes`]) uploaded once, decoded on the GPU for a
//! list of attribute indices (entry `decode_attrs`, CPU twin
//! [`Attributes::decode`]). Parity: the test below, every leaf of a
//! depth-8 sphere in both forms.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use crate::error::{Error, Result};
use crate::voxels::attributes::{AttrForm, Attributes};

/// Uniform of `kernels/voxel_attrs.wgsl` (keep in sync with `struct AttrParams` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct AttrParams {
    pub n: u32,
    /// 1: plain, 2: DXT.
    pub form: u32,
    pub leaves: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<AttrParams>() == 16);

/// One decoded attribute (keep in sync with `struct Attr` there): `valid`
/// is 0 for an index past the leaves (colour and normal then zero).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuAttr {
    pub colour: [f32; 3],
    pub valid: u32,
    pub normal: [f32; 3],
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<GpuAttr>() == 32);

/// A scene's attributes on the GPU and the `decode_attrs` pipeline.
pub struct GpuAttrs<'c> {
    ctx: &'c GpuContext,
    plain: wgpu::Buffer,
    colour: wgpu::Buffer,
    normal: wgpu::Buffer,
    leaves: u32,
    decode: wgpu::ComputePipeline,
}

/// A non-empty slice for a binding (wgpu refuses zero-sized buffers).
fn nonempty(v: Vec<u32>) -> Vec<u32> {
    if v.is_empty() {
        vec![0]
    } else {
        v
    }
}

impl<'c> GpuAttrs<'c> {
    /// Uploads both stored forms of `a`.
    pub fn new(ctx: &'c GpuContext, a: &Attributes) -> Result<GpuAttrs<'c>> {
        let leaves = u32::try_from(a.leaves)
            .map_err(|_| Error::invalid("gpu voxel attributes", "more than 2^32 leaves"))?;
        let plain = a
            .plain
            .iter()
            .flat_map(|w| [w[0] as u32 | (w[1] as u32) << 16, w[2] as u32])
            .collect();
        let colour = a.dxt_colour.iter().flatten().copied().collect();
        let normal = a.dxt_normal.iter().flatten().copied().collect();
        Ok(GpuAttrs {
            ctx,
            plain: storage_in(ctx, "voxel plain attributes", &nonempty(plain))?,
            colour: storage_in(ctx, "voxel dxt colour", &nonempty(colour))?,
            normal: storage_in(ctx, "voxel dxt normal", &nonempty(normal))?,
            leaves,
            decode: pipeline(ctx, "voxel_attrs", "decode_attrs")?,
        })
    }

    /// Decodes the attributes `idx` in form `form` (`AttrForm::None` is refused).
    pub fn decode(&self, form: AttrForm, idx: &[u32]) -> Result<Vec<GpuAttr>> {
        let code = match form {
            AttrForm::None => {
                return Err(Error::invalid("attributes", "no stored form to decode"));
            }
            AttrForm::Plain => 1,
            AttrForm::Dxt => 2,
        };
        let n = idx.len();
        if n == 0 {
            return Ok(Vec::new());
        }
        let p = AttrParams {
            n: u32::try_from(n)
                .map_err(|_| Error::invalid("gpu voxel attributes", "more than 2^32 rays"))?,
            form: code,
            leaves: self.leaves,
            _pad: 0,
        };
        let u = uniform(self.ctx, "voxel attr params", &p);
        let ib = storage_in(self.ctx, "voxel attr indices", idx)?;
        let ob = storage_out(self.ctx, "voxel attrs out", 32 * n as u64)?;
        let pass = Pass {
            label: "decode_attrs",
            pipeline: &self.decode,
            buffers: &[
                (0, &u),
                (1, &ib),
                (2, &self.plain),
                (3, &self.colour),
                (4, &self.normal),
                (5, &ob),
            ],
            n: n as u64,
            wg: 64,
        };
        run(self.ctx, "decode_attrs", &[pass], &[&ob])?.take(0, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::attributes::leaf_normals;
    use crate::voxels::octree::build;
    use crate::voxels::shape::Shape;

    /// Every leaf of a depth-8 sphere (37k leaves) plus two indices past the
    /// end, plain and DXT: the GPU decode equals the CPU's within 2^-20
    /// per component (an FMA-contracting driver moves a component by an
    /// ulp or two); on lavapipe it is bit-identical (asserted by count).
    #[test]
    fn gpu_attribute_decode_equals_the_cpu_decode_on_every_leaf() {
        let Ok(ctx) = GpuContext::get() else {
            eprintln!("no GPU adapter: skipped");
            return;
        };
        let s = Shape::Sphere { radius: 0.8 };
        let tree = build(&s, 8, &MemBudget::fixed(1 << 30)).unwrap();
        let a = Attributes::build(&leaf_normals(&s, &tree).unwrap());
        let g = GpuAttrs::new(ctx, &a).unwrap();
        let mut idx: Vec<u32> = (0..a.leaves as u32).collect();
        idx.extend([a.leaves as u32, u32::MAX]);
        for form in [AttrForm::Plain, AttrForm::Dxt] {
            let got = g.decode(form, &idx).unwrap();
            let (mut worst, mut same) = (0f32, 0usize);
            for (k, &i) in idx.iter().enumerate() {
                let Some((c, n)) = (i < a.leaves as u32)
                    .then(|| a.decode(form, i as usize))
                    .flatten()
                else {
                    assert_eq!(got[k], GpuAttr::default(), "{form:?} index {i}");
                    continue;
                };
                assert_eq!(got[k].valid, 1);
                let want = [c, n].concat();
                let have = [got[k].colour, got[k].normal].concat();
                let e = (0..6)
                    .map(|j| (want[j] - have[j]).abs())
                    .fold(0f32, f32::max);
                worst = worst.max(e);
                same += (want == have) as usize;
            }
            eprintln!(
                "{form:?}: {same} of {} bit-identical, max |diff| {worst:e}",
                a.leaves
            );
            assert!(worst <= 2f32.powi(-20), "{form:?}: max |diff| {worst:e}");
        }
    }
}
