//! End-to-end tests of rows of the operation table (`judge/ops/`): a
//! scene and parameters through `ops::find(name).run`, as the worker calls
//! them. Tests of one stage or referee live beside it; these check that
//! rows agree with each other (the cast against the referee and the
//! closed-form bounds).

use crate::budget::MemBudget;
use crate::judge::ops::BackendKind;
use crate::judge::ops::OpCtx;
use crate::real::Precision;
use crate::scene::SceneDoc;
use crate::tensor::Outputs;
use serde_yaml::Value;

const SPHERE: &str = "renderer: voxels\nshape: {type: sphere, radius: 0.8}\ndepth: 6\n\
    camera: {type: pinhole, position: [2.0, 1.5, 2.5], target: [0, 0, 0], fov_y: 45}\nwidth: 48\nheight: 40\n";

fn run(op: &str, scene: &str, params: &str, precision: Precision) -> Outputs {
    let doc = SceneDoc {
        path: "t.yaml".into(),
        value: serde_yaml::from_str(scene).unwrap(),
    };
    let params: Value = serde_yaml::from_str(params).unwrap();
    let ctx = OpCtx {
        case_id: "t",
        scene: Some(&doc),
        params: &params,
        backend: BackendKind::Cpu,
        precision,
        seed: 1,
        budget: MemBudget::fixed(1 << 30),
        dump: false,
        rays: None,
        root: std::path::Path::new("."),
    };
    (crate::judge::ops::find(op).unwrap().run)(&ctx).unwrap()
}

#[test]
fn render_writes_scenes_outputs_with_their_shapes_and_dtypes() {
    let out = run("voxels.render", SPHERE, "{}", Precision::F32);
    let t = &out.tensors;
    assert_eq!(
        (t["hit"].dtype(), t["hit"].shape()),
        ("uint8", &[40usize, 48][..])
    );
    assert_eq!(
        (t["t"].dtype(), t["leaf"].dtype(), t["leaf"].shape()),
        ("float32", "int32", &[40usize, 48, 3][..])
    );
    assert_eq!(t["image"].shape(), &[40, 48, 3]);
    assert!(out.counters["hits"] > 300);
    let hit = t["hit"].to_f64_vec();
    let leaf = t["leaf"].to_f64_vec();
    let tt = t["t"].to_f64_vec();
    for i in 0..hit.len() {
        if hit[i] == 0.0 {
            assert_eq!((tt[i], leaf[3 * i]), (-1.0, -1.0));
        }
    }
}

#[test]
fn render_and_referee_agree_on_untied_camera_and_hard_rays() {
    for params in ["{}", "{rays: hard, count: 60}"] {
        let a = run("voxels.render", SPHERE, params, Precision::F64);
        let r = run("voxels.referee", SPHERE, params, Precision::F64);
        let untied = r.tensors["untied"].to_f64_vec();
        for name in ["hit", "t", "normal", "leaf"] {
            let x = a.tensors[name].to_f64_vec();
            let y = r.tensors[name].to_f64_vec();
            let k = x.len() / untied.len();
            for i in 0..x.len() {
                if untied[i / k] == 1.0 {
                    assert!(
                        (x[i] - y[i]).abs() <= 1e-12 * y[i].abs().max(1.0),
                        "{params} {name} {i}: {} {}",
                        x[i],
                        y[i]
                    );
                }
            }
        }
    }
}

#[test]
fn sphere_hits_lie_between_the_bounding_spheres() {
    let a = run("voxels.render", SPHERE, "{}", Precision::F64);
    let b = run("voxels.sphere_bounds", SPHERE, "{}", Precision::F64);
    let (hit, t) = (a.tensors["hit"].to_f64_vec(), a.tensors["t"].to_f64_vec());
    let (to, ti, mi) = (
        b.tensors["t_outer"].to_f64_vec(),
        b.tensors["t_inner"].to_f64_vec(),
        b.tensors["meets_inner"].to_f64_vec(),
    );
    for i in 0..hit.len() {
        if hit[i] == 1.0 {
            assert!(t[i] >= to[i] && to[i] >= 0.0);
        }
        if mi[i] == 1.0 {
            assert!(hit[i] == 1.0 && t[i] <= ti[i]);
        }
    }
}
