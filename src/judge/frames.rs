//! `hpjudge render SCENE --all-frames`: every frame of the scene's NeRF
//! camera file (`camera: {type: nerf}`, scene/nerf.rs), each rendered as
//! `--set camera.frame=I` would and written to `OUT/frame_IIII/`, with a
//! progress bar and ETA on a terminal (progress.rs).

use std::path::{Path, PathBuf};

use super::artifacts::write_tensor;
use super::progress;
use super::render::{render, RenderRequest};
use crate::error::{Error, Result};
use crate::scene::{nerf, parse_sets, SceneDoc};

/// The folder of frame `i` under `out`.
pub fn frame_dir(out: &Path, i: usize) -> PathBuf {
    out.join(format!("frame_{i:04}"))
}

/// Renders every frame; calls `each` with every file written. Returns the frame count.
pub fn render_all(req: &RenderRequest, out: &Path, mut each: impl FnMut(&Path)) -> Result<usize> {
    let doc = SceneDoc::load_raw(req.scene, &parse_sets(req.set)?)?;
    let frames = nerf::frames(&doc)?.ok_or_else(|| {
        Error::invalid(
            doc.at(),
            "--all-frames needs a NeRF camera: `camera: {type: nerf, transforms: FILE}`",
        )
    })?;
    let bar = progress::bar(frames.len() as u64, false);
    for (i, f) in frames.iter().enumerate() {
        bar.set_message(f.name.clone());
        let mut set = req.set.to_vec();
        set.push(format!("camera.frame={i}"));
        let outputs = render(&RenderRequest { set: &set, ..*req })?;
        let dir = frame_dir(out, i);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        for (n, t) in &outputs.tensors {
            for p in write_tensor(&dir, n, t)? {
                bar.suspend(|| each(&p));
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(frames.len())
}
