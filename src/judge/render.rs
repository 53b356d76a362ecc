//! `hpjudge render`: one scene through its renderer's `render` operation,
//! outside any manifest (replaying dumped rays, or a gradient image).

use std::path::Path;

use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::judge::ops::{self, BackendKind, OpCtx};
use crate::real::Precision;
use crate::scene::{parse_pairs, SceneDoc};
use crate::tensor::{Outputs, Tensor};

/// What `hpjudge render` was asked for.
#[derive(Clone, Copy)]
pub struct RenderRequest<'a> {
    pub scene: &'a Path,
    pub backend: BackendKind,
    pub precision: Precision,
    /// `key=value` scene overrides (dotted paths allowed).
    pub set: &'a [String],
    /// `key=value` parameters of the `render` operation (`--param`), as a
    /// manifest case's `params:`.
    pub params: &'a [String],
    /// Rays to replay: an (N, 9) `.npy` written by `--dump-failing`.
    pub rays: Option<&'a Path>,
    /// dL/d rgb (H, W, 3) for renderers with gradients.
    pub grad_from: Option<&'a Path>,
    pub seed: u32,
    pub budget: MemBudget,
}

/// Renderers whose `render` operation replays `--rays` (reads `OpCtx::rays`);
/// the others are refused rather than rendering their camera silently.
const REPLAYS_RAYS: [&str; 3] = ["rays", "volume", "voxels"];

/// Loads the scene and runs `<renderer>.render` on it.
pub fn render(req: &RenderRequest) -> Result<Outputs> {
    let doc = SceneDoc::load(req.scene, req.set)?;
    let renderer = doc.renderer()?.to_string();
    let name = format!("{renderer}.render");
    let op = ops::find(&name).ok_or_else(|| {
        Error::NotSupported(format!("renderer {renderer:?} has no `render` operation"))
    })?;
    if req.grad_from.is_some() && !op.params.contains(&"grad_from") {
        let why = format!("{name} has no gradients: --grad-from is not supported");
        return Err(Error::NotSupported(why));
    }
    if req.rays.is_some() && !REPLAYS_RAYS.contains(&renderer.as_str()) {
        let why = format!("{name} does not replay rays: --rays is not supported");
        return Err(Error::NotSupported(why));
    }
    let rays_t = req
        .rays
        .map(|p| Tensor::read_npy_within(p, req.budget))
        .transpose()?;
    let mut params = serde_yaml::Mapping::new();
    for (k, v) in parse_pairs("--param", req.params)? {
        let at = format!("--param {k}");
        if k == "grad_from" {
            return Err(Error::invalid(
                at,
                "give the gradient image with --grad-from",
            ));
        }
        if let Some(why) = op.refuses_param(&k) {
            return Err(Error::invalid(at, why));
        }
        params.insert(k.into(), v);
    }
    if let Some(g) = req.grad_from {
        params.insert("grad_from".into(), g.display().to_string().into());
    }
    let params = serde_yaml::Value::Mapping(params);
    let root = req.scene.parent().unwrap_or(Path::new(".")).to_path_buf();
    let ctx = OpCtx {
        case_id: "render",
        scene: Some(&doc),
        params: &params,
        backend: req.backend,
        precision: req.precision,
        seed: req.seed,
        budget: req.budget,
        dump: false,
        rays: rays_t.as_ref(),
        root: &root,
    };
    op.call(&ctx)
}
