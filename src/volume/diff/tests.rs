//! Unit tests of `f_diff` (FD referees in f64, closed forms, determinism).

use super::*;
use crate::rng::rand_f64;
use crate::volume::field::{Analytic, ColorDesc, GridDesc, Oob};
use crate::volume::sample::{Sampling, TransPath};

fn params(field: FieldDesc, color: ColorDesc, es: f64) -> VolumeParams {
    VolumeParams {
        field,
        color,
        dt: 0.05,
        max_steps: 1024,
        early_stop: es,
        sampling: Sampling::Fixed,
        path: TransPath::Product,
        background: [0.1, 0.2, 0.3],
        occupancy: 0,
    }
}

fn cam() -> Camera {
    Camera::pinhole_look_at([0.3, 0.2, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6).unwrap()
}

fn up<F: Real>(n: usize) -> Upstream<F> {
    Upstream {
        rgb: (0..n)
            .map(|i| [0, 1, 2].map(|c| F::of(rand_f64(7, i as u32, 0, c) - 0.3)))
            .collect(),
        depth: None,
        opacity: None,
    }
}

fn grid_params() -> VolumeParams {
    let sig = GridDesc::sample([5, 6, 7], [-1.0; 3], [1.0; 3], Oob::Zero, |x| {
        3.0 + 2.0 * x[0] - x[1] * x[2]
    });
    let mut col = GridDesc::filled([4, 4, 4], &[0.5, 0.5, 0.5], [-1.0; 3], [1.0; 3], Oob::Clamp);
    for (i, v) in col.data.iter_mut().enumerate() {
        *v = 0.2 + 0.6 * rand_f64(3, i as u32, 0, 0);
    }
    params(FieldDesc::Grid(sig), ColorDesc::Grid(col), 0.0)
}

fn run<F: Real>(p: &VolumeParams, chain: Chain, reduce: Reduce) -> Grads<F> {
    let gen = RayGen::new(8, 6);
    let opt = DiffOptions {
        chain,
        reduce,
        per_sample: true,
    };
    f_diff::<F>(
        &cam(),
        &gen,
        p,
        &up(48),
        &opt,
        None,
        &MemBudget::fixed(1 << 28),
    )
    .unwrap()
}

/// L = sum W . rgb of a plain f64 render with the node perturbed.
fn loss(p: &VolumeParams, c: &Camera) -> f64 {
    let gen = RayGen::new(8, 6);
    let r = crate::volume::render::<f64>(
        c,
        &gen,
        p,
        Chain::Fused,
        crate::volume::compose::Compose::Sorted,
        &MemBudget::fixed(1 << 28),
    )
    .unwrap();
    let w = up::<f64>(48).rgb;
    r.image
        .rgb
        .iter()
        .zip(&w)
        .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
        .sum()
}

#[test]
fn constant_medium_gradient_is_l_exp_minus_tau_times_c_minus_b() {
    // One ortho ray along -z through [-1, 1]: L = 2.
    let c = Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
    let mut p = params(
        FieldDesc::Analytic(Analytic::Constant { s: 2.0 }),
        ColorDesc::Constant([1.0, 0.5, 0.25]),
        0.0,
    );
    p.dt = 0.01;
    let gen = RayGen::new(2, 2);
    let u = Upstream {
        rgb: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0; 3]],
        depth: None,
        opacity: None,
    };
    for chain in [Chain::Fused, Chain::Unfused] {
        let opt = DiffOptions {
            chain,
            reduce: Reduce::Sorted,
            per_sample: false,
        };
        let g = f_diff::<f64>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
        let expect: f64 = (0..3)
            .map(|ch| 2.0 * (-4.0f64).exp() * ([1.0, 0.5, 0.25][ch] - [0.1, 0.2, 0.3][ch]))
            .sum();
        let got = g.dsigma_param.unwrap()[0];
        assert!(
            (got - expect).abs() < 1e-12 * expect.abs(),
            "{got} {expect}"
        );
        let op = -(-4.0f64).exp_m1();
        let dc = g.dcolor_const.unwrap();
        assert!(
            (dc[0] - op).abs() < 1e-13 && (dc[2] - op).abs() < 1e-13,
            "{dc:?}"
        );
    }
}

#[test]
fn grid_node_gradients_match_central_differences_f64() {
    let p = grid_params();
    let g = run::<f64>(&p, Chain::Fused, Reduce::Sorted);
    let ds = g.dsigma.unwrap();
    let dc = g.dcolor.unwrap();
    let FieldDesc::Grid(sg) = &p.field else {
        unreachable!()
    };
    let ColorDesc::Grid(cg) = &p.color else {
        unreachable!()
    };
    let h = 1e-6;
    let big = ds.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    for node in [100, 117, 130, 155, 170] {
        let mut q = p.clone();
        let mut s2 = sg.clone();
        s2.data[node] += h;
        q.field = FieldDesc::Grid(s2.clone());
        let lp = loss(&q, &cam());
        s2.data[node] -= 2.0 * h;
        q.field = FieldDesc::Grid(s2);
        let lm = loss(&q, &cam());
        let fd = (lp - lm) / (2.0 * h);
        assert!(
            (fd - ds[node]).abs() <= 1e-6 * big.max(1e-3),
            "node {node}: {fd} vs {}",
            ds[node]
        );
    }
    let bigc = dc.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    for idx in [63, 64, 100, 121, 130] {
        let mut q = p.clone();
        let mut c2 = cg.clone();
        c2.data[idx] += h;
        q.color = ColorDesc::Grid(c2.clone());
        let lp = loss(&q, &cam());
        c2.data[idx] -= 2.0 * h;
        q.color = ColorDesc::Grid(c2);
        let lm = loss(&q, &cam());
        let fd = (lp - lm) / (2.0 * h);
        assert!(
            (fd - dc[idx]).abs() <= 1e-6 * bigc.max(1e-3),
            "colour {idx}: {fd} vs {}",
            dc[idx]
        );
    }
}

#[test]
fn a_ray_leaving_through_an_edge_gets_the_mean_of_its_one_sided_derivatives() {
    // Pixel (1, 0) of the centred 8 x 6 view leaves the box exactly
    // through the edge x = -1, y = 1 (|d_x| = |d_y|): t1 has a kink.
    let c =
        Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6).unwrap();
    let mut p = params(
        FieldDesc::Analytic(Analytic::Gaussian {
            amplitude: 8.0,
            mean: [0.0; 3],
            std: 0.4,
        }),
        ColorDesc::Constant([1.0, 0.5, 0.25]),
        0.0,
    );
    p.dt = 0.01;
    let mut gen = RayGen::new(8, 6);
    gen.roi = Some(crate::rays::Roi {
        x: 1,
        y: 0,
        width: 1,
        height: 1,
    });
    let opt = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let upr = Upstream {
        rgb: vec![[1.0, 0.3, -0.2]],
        depth: None,
        opacity: None,
    };
    let b = MemBudget::fixed(1 << 24);
    let g = f_diff::<f64>(&c, &gen, &p, &upr, &opt, None, &b).unwrap();
    let lossg = |cc: &Camera| {
        let r = crate::volume::render::<f64>(
            cc,
            &gen,
            &p,
            Chain::Fused,
            crate::volume::compose::Compose::Sorted,
            &b,
        )
        .unwrap();
        r.image.rgb[0][0] + 0.3 * r.image.rgb[0][1] - 0.2 * r.image.rgb[0][2]
    };
    let h = 1e-6;
    for q in 0..6 {
        let mut xi = [0.0; 6];
        xi[q] = h;
        let lp = lossg(&perturb(&c, xi));
        xi[q] = -h;
        let lm = lossg(&perturb(&c, xi));
        let fd = (lp - lm) / (2.0 * h);
        assert!((fd - g.dcam[q]).abs() < 1e-5, "{q}: {fd} {:?}", g.dcam);
    }
}

#[test]
fn pose_gradient_matches_central_differences_f64() {
    for p in [
        grid_params(),
        params(
            FieldDesc::Analytic(Analytic::Gaussian {
                amplitude: 8.0,
                mean: [0.1, 0.0, -0.1],
                std: 0.4,
            }),
            ColorDesc::Constant([1.0, 0.5, 0.25]),
            0.0,
        ),
    ] {
        let g = run::<f64>(&p, Chain::Fused, Reduce::Sorted);
        let h = 1e-6;
        for q in 0..6 {
            let mut xi = [0.0; 6];
            xi[q] = h;
            let lp = loss(&p, &perturb(&cam(), xi));
            xi[q] = -h;
            let lm = loss(&p, &perturb(&cam(), xi));
            let fd = (lp - lm) / (2.0 * h);
            let scale = g.dcam.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            assert!(
                (fd - g.dcam[q]).abs() <= 2e-4 * scale,
                "component {q}: fd {fd} vs {:?}",
                g.dcam
            );
        }
    }
}

/// C2W exp(xi) for a single-component xi (pure translation or rotation).
fn perturb(c: &Camera, xi: [f64; 6]) -> Camera {
    let m = *c.c2w();
    let w = [xi[3], xi[4], xi[5]];
    let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    let mut e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if th > 0.0 {
        let k = w.map(|v| v / th);
        let kx = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
        for i in 0..3 {
            for j in 0..3 {
                let kk: f64 = (0..3).map(|l| kx[i][l] * kx[l][j]).sum();
                e[i][j] += th.sin() * kx[i][j] + (1.0 - th.cos()) * kk;
            }
        }
    }
    let mut out = m;
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = (0..3).map(|l| m[i][l] * e[l][j]).sum();
        }
        out[i][3] = m[i][3] + (0..3).map(|l| m[i][l] * xi[l]).sum::<f64>();
    }
    c.with_c2w(out)
}

#[test]
fn fused_equals_unfused_bit_for_bit_and_chunked_agrees_with_sorted() {
    let p = grid_params();
    for es in [0.0, 1e-2] {
        let q = VolumeParams {
            early_stop: es,
            ..p.clone()
        };
        let a = run::<f32>(&q, Chain::Fused, Reduce::Sorted);
        let b = run::<f32>(&q, Chain::Unfused, Reduce::Sorted);
        assert_eq!(a.dsigma, b.dsigma);
        assert_eq!(a.dcolor, b.dcolor);
        assert_eq!(a.dcam, b.dcam);
        let c = run::<f32>(&q, Chain::Fused, Reduce::Chunked { chunks: 3 });
        let d = run::<f32>(&q, Chain::Unfused, Reduce::Chunked { chunks: 3 });
        assert_eq!(c.dsigma, d.dsigma);
        let (x, y) = (a.dsigma.unwrap(), c.dsigma.unwrap());
        let big = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        for (u, v) in x.iter().zip(&y) {
            assert!((u - v).abs() <= 1e-5 * big, "{u} {v}");
        }
    }
}

#[test]
fn sorted_reduction_is_bit_identical_across_thread_counts() {
    let p = grid_params();
    let one = crate::parallel::with_threads(1, || run::<f32>(&p, Chain::Fused, Reduce::Sorted));
    let two = crate::parallel::with_threads(2, || run::<f32>(&p, Chain::Fused, Reduce::Sorted));
    let again = crate::parallel::with_threads(3, || {
        run::<f32>(&p, Chain::Unfused, Reduce::Chunked { chunks: 4 })
    });
    let again2 = crate::parallel::with_threads(1, || {
        run::<f32>(&p, Chain::Unfused, Reduce::Chunked { chunks: 4 })
    });
    assert_eq!(
        one,
        Grads {
            time_s: one.time_s,
            ..two
        }
    );
    assert_eq!(again.dsigma, again2.dsigma);
    assert_eq!(again.dcolor, again2.dcolor);
}

#[test]
fn huge_density_gives_finite_gradients_of_the_right_sign() {
    let c = Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
    let p = VolumeParams {
        dt: 0.01,
        ..params(
            FieldDesc::Analytic(Analytic::Constant { s: 1e4 }),
            ColorDesc::Constant([1.0, 0.5, 0.25]),
            1e-4,
        )
    };
    let gen = RayGen::new(2, 2);
    let u = Upstream {
        rgb: vec![[1.0, 0.0, 0.0]; 4],
        depth: Some(vec![1.0; 4]),
        opacity: Some(vec![1.0; 4]),
    };
    let opt = DiffOptions {
        chain: Chain::Unfused,
        reduce: Reduce::Sorted,
        per_sample: true,
    };
    let g = f_diff::<f32>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
    let s = g.dsigma_samples.unwrap();
    assert!(s.iter().all(|v| v.is_finite()));
    // The first sample: more density there brings the (nearer) colour
    // forward: d rgb_r / d sigma_0 = T_1 c_r dt >= 0, and depth shrinks.
    assert!(g.dcam.iter().all(|v| v.is_finite()));
    assert!(g.dsigma_param.unwrap()[0].is_finite());
    assert!(s[0] >= 0.0);
}

#[test]
fn tiny_optical_depth_keeps_relative_accuracy_in_f32() {
    // sigma dt = 1e-9: dC/dsigma = L e^{-tau} (c - b), tau ~ 2e-7.
    let c = Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
    let p = VolumeParams {
        dt: 0.01,
        ..params(
            FieldDesc::Analytic(Analytic::Constant { s: 1e-7 }),
            ColorDesc::Constant([1.0, 0.5, 0.25]),
            0.0,
        )
    };
    let gen = RayGen::new(1, 1);
    let u = Upstream {
        rgb: vec![[1.0, 0.0, 0.0]],
        depth: None,
        opacity: None,
    };
    let opt = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let g = f_diff::<f32>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
    let got = g.dsigma_param.unwrap()[0] as f64;
    let expect = 2.0 * (-2e-7f64).exp() * 0.9;
    assert!(((got - expect) / expect).abs() < 1e-5, "{got} {expect}");
}

/// Bits of every gradient the lanes produce, for an exact comparison
/// (-0 and NaN included).
fn grad_bits(g: &Grads<f32>) -> Vec<u32> {
    let mut v: Vec<u32> = g.dsigma.iter().flatten().map(|x| x.to_bits()).collect();
    v.extend(g.dcolor.iter().flatten().map(|x| x.to_bits()));
    v.extend(g.dcam.map(f32::to_bits));
    v.push(g.samples as u32);
    v
}

#[test]
fn lane_backward_equals_the_scalar_walk_bit_for_bit() {
    // A packed 8 x 7 x 9 grid, densities in [-5, 60] (fmax, alpha's expf
    // branch and early stops all occur), rays clipped to a box larger than
    // the grid (cells on and beyond the border), upstream rgb, depth and
    // opacity gradients.
    let shape = [8, 7, 9];
    let mut sig = GridDesc::sample(shape, [-1.0; 3], [1.0; 3], Oob::Zero, |_| 0.0);
    for (i, v) in sig.data.iter_mut().enumerate() {
        let u = rand_f64(11, i as u32, 0, 0);
        *v = -5.0 + 65.0 * u * u;
    }
    let mut col = GridDesc::filled(shape, &[0.5; 3], [-1.0; 3], [1.0; 3], Oob::Zero);
    for (i, v) in col.data.iter_mut().enumerate() {
        *v = rand_f64(12, i as u32, 0, 0);
    }
    let (w, h) = (24u32, 20u32);
    let mut gen = RayGen::new(w, h);
    gen.aabb = crate::rays::Aabb {
        min: [-1.2; 3],
        max: [1.1; 3],
    };
    let cam =
        Camera::pinhole_look_at([0.3, 0.2, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 50.0, w, h).unwrap();
    let n = (w * h) as usize;
    let mut u = up::<f32>(n);
    let r = |s: u32| (0..n).map(move |i| rand_f64(s, i as u32, 0, 0) as f32 - 0.5);
    u.depth = Some(r(13).collect());
    u.opacity = Some(r(14).collect());
    let budget = MemBudget::fixed(1 << 28);
    let mut seen = 0u64;
    for es in [0.0, 1e-3] {
        let p = VolumeParams {
            dt: 0.01,
            ..params(
                FieldDesc::Grid(sig.clone()),
                ColorDesc::Grid(col.clone()),
                es,
            )
        };
        let medium = Medium::<f32>::new(&p.field, &p.color);
        let march = p.march::<f32>();
        if crate::volume::fused_lanes::LaneMarch::new(&medium, &march, None).is_none() {
            eprintln!("no AVX2: the lanes are not used here; skipped");
            return;
        }
        for reduce in [Reduce::Sorted, Reduce::Chunked { chunks: 3 }] {
            let opt = DiffOptions {
                chain: Chain::Fused,
                reduce,
                per_sample: false,
            };
            let prep = prepare::<f32>(&p, &gen.aabb, &budget).unwrap();
            let run = |k| {
                f_diff_prepared::<f32>(&cam, &gen, &p, &prep, &u, &opt, None, &budget, k).unwrap()
            };
            let (lanes, scalar) = (run(Kernel::Lanes), run(Kernel::Scalar));
            assert_eq!(grad_bits(&lanes), grad_bits(&scalar), "es {es} {reduce:?}");
            seen += scalar.samples;
        }
    }
    assert!(seen > 100_000, "{seen}");
}
