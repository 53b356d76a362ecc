//! The finite-difference referee of the backward pass, f64: central
//! differences of the loss of the forward render (fused, early stop and
//! skipping off) at the probes, every analytic parameter and every pose
//! component. It never calls `volume::diff`, the stage it checks; the
//! forward render it differences is judged by the forward cases.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::Compose;
use crate::volume::field::{Analytic, ColorDesc, FieldDesc};
use crate::volume::loss::{probe_colors, probe_nodes, LossWeights, ProbeSpec};
use crate::volume::{render, Chain, VolumeParams};

/// `L` of an f64 fused render, summed per pixel in order.
pub fn fd_loss(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    w: &LossWeights,
    budget: &MemBudget,
) -> Result<Vec<f64>> {
    let r = render::<f64>(cam, gen, p, Chain::Fused, Compose::Sorted, budget)?;
    let img = &r.image;
    Ok((0..img.rgb.len())
        .map(|i| {
            let c = img.rgb[i];
            w.rgb[i][0] * c[0]
                + w.rgb[i][1] * c[1]
                + w.rgb[i][2] * c[2]
                + w.depth * img.depth[i]
                + w.opacity * img.opacity[i]
        })
        .collect())
}

/// Central difference `(L+ - L-) / (2h)`, differenced per pixel first so
/// untouched pixels contribute exactly 0.
pub fn central(lp: &[f64], lm: &[f64], h: f64) -> f64 {
    lp.iter().zip(lm).map(|(a, b)| a - b).sum::<f64>() / (2.0 * h)
}

/// C2W exp(xi) for `xi = h e_q` (SCENES.md delta): a pure translation
/// `R rho`, or a rotation by Rodrigues' formula.
pub fn perturb_pose(cam: &Camera, q: usize, h: f64) -> Camera {
    let m = *cam.c2w();
    let mut e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut rho = [0.0; 3];
    if q < 3 {
        rho[q] = h;
    } else {
        let (s, c) = h.sin_cos();
        let (a, b) = ((q - 3 + 1) % 3, (q - 3 + 2) % 3);
        // Rotation about axis q - 3 by angle h.
        e[a][a] = c;
        e[b][b] = c;
        e[a][b] = -s;
        e[b][a] = s;
    }
    let mut out = m;
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = (0..3).map(|l| m[i][l] * e[l][j]).sum();
        }
        out[i][3] = m[i][3] + (0..3).map(|l| m[i][l] * rho[l]).sum::<f64>();
    }
    cam.with_c2w(out)
}

/// Finite-difference gradients of the loss `w` of scene `p` seen by `cam`
/// through `gen`, with steps `h = [h_sigma, h_color, h_pose]` (density steps
/// scale with `max(|value|, 1)` and stop at 0): tensors `dsigma_probe` or
/// `dsigma_param`, `dcolor_probe` or `dcolor_const`, `dcam`; counter
/// `renders`.
pub fn grad_fd(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    w: &LossWeights,
    probes: &ProbeSpec,
    [h_sigma, h_color, h_pose]: [f64; 3],
    budget: &MemBudget,
) -> Result<Outputs> {
    let p = VolumeParams {
        early_stop: 0.0,
        occupancy: 0,
        ..p.clone()
    };
    let mut out = Outputs::default();
    let mut renders = 0u64;
    let mut fd = |q: &VolumeParams, qm: &VolumeParams, c: &Camera, cm: &Camera, h: f64| {
        renders += 2;
        Ok::<f64, Error>(central(
            &fd_loss(c, gen, q, w, budget)?,
            &fd_loss(cm, gen, qm, w, budget)?,
            h,
        ))
    };
    // Density.
    match &p.field {
        FieldDesc::Grid(g) => {
            let idx = probe_nodes(g.shape, probes.sigma, probes.seed, 0);
            let mut v = Vec::with_capacity(idx.len());
            for &node in &idx {
                let h = h_sigma * g.data[node].abs().max(1.0);
                let (mut gp, mut gm) = (g.clone(), g.clone());
                gp.data[node] += h;
                gm.data[node] = (gm.data[node] - h).max(0.0);
                let hh = (gp.data[node] - gm.data[node]) / 2.0;
                let qp = VolumeParams {
                    field: FieldDesc::Grid(gp),
                    ..p.clone()
                };
                let qm = VolumeParams {
                    field: FieldDesc::Grid(gm),
                    ..p.clone()
                };
                v.push(fd(&qp, &qm, cam, cam, hh)?);
            }
            out.tensor("dsigma_probe", Tensor::real(&[v.len()], v)?);
        }
        FieldDesc::Analytic(a) => {
            let params: Vec<f64> = match a {
                Analytic::Constant { s } => vec![*s],
                Analytic::Slabs { sigma, .. } => sigma.clone(),
                _ => vec![],
            };
            if !params.is_empty() {
                let mut v = Vec::with_capacity(params.len());
                for i in 0..params.len() {
                    let h = h_sigma * params[i].abs().max(1.0);
                    let with = |d: f64| {
                        let a2 = match a.clone() {
                            Analytic::Constant { s } => Analytic::Constant { s: s + d },
                            Analytic::Slabs {
                                axis,
                                breaks,
                                mut sigma,
                            } => {
                                sigma[i] += d;
                                Analytic::Slabs {
                                    axis,
                                    breaks,
                                    sigma,
                                }
                            }
                            other => other,
                        };
                        VolumeParams {
                            field: FieldDesc::Analytic(a2),
                            ..p.clone()
                        }
                    };
                    let hm = h.min(params[i]);
                    let (qp, qm) = (with(h), with(-hm));
                    v.push(fd(&qp, &qm, cam, cam, (h + hm) / 2.0)?);
                }
                out.tensor("dsigma_param", Tensor::real(&[v.len()], v)?);
            }
        }
        // Hash-grid parameters: `volume.hash_grad_fd` (ops/volume_hash.rs).
        FieldDesc::HashMlp(_) => {}
    }
    // Colour.
    match &p.color {
        ColorDesc::Grid(g) => {
            let idx = probe_colors(g.shape, probes.color, probes.seed);
            let mut v = Vec::with_capacity(idx.len());
            for &i in &idx {
                let (mut gp, mut gm) = (g.clone(), g.clone());
                gp.data[i] += h_color;
                gm.data[i] -= h_color;
                let qp = VolumeParams {
                    color: ColorDesc::Grid(gp),
                    ..p.clone()
                };
                let qm = VolumeParams {
                    color: ColorDesc::Grid(gm),
                    ..p.clone()
                };
                v.push(fd(&qp, &qm, cam, cam, h_color)?);
            }
            out.tensor("dcolor_probe", Tensor::real(&[v.len()], v)?);
        }
        ColorDesc::Constant(c) => {
            let mut v = Vec::with_capacity(3);
            for ch in 0..3 {
                let (mut cp, mut cm) = (*c, *c);
                cp[ch] += h_color;
                cm[ch] -= h_color;
                let qp = VolumeParams {
                    color: ColorDesc::Constant(cp),
                    ..p.clone()
                };
                let qm = VolumeParams {
                    color: ColorDesc::Constant(cm),
                    ..p.clone()
                };
                v.push(fd(&qp, &qm, cam, cam, h_color)?);
            }
            out.tensor("dcolor_const", Tensor::real(&[3], v)?);
        }
        // Hash-grid parameters: `volume.hash_grad_fd` (ops/volume_hash.rs).
        ColorDesc::Mlp => {}
    }
    // Pose.
    let mut dcam = Vec::with_capacity(6);
    for q in 0..6 {
        let (cp, cm) = (perturb_pose(cam, q, h_pose), perturb_pose(cam, q, -h_pose));
        dcam.push(fd(&p, &p, &cp, &cm, h_pose)?);
    }
    out.tensor("dcam", Tensor::real(&[6], dcam)?);
    out.counter("renders", renders);
    Ok(out)
}
