//! `camera: {type: nerf, transforms: FILE, frame: I}`: frame I (default 0)
//! of a NeRF camera file (`transforms.json`, read by `camera::nerf`; FILE
//! relative to the scene). On load the block becomes the `pinhole_k`
//! camera of that frame, scaled to the scene's `width` x `height`; a scene
//! without `width`/`height` takes the file's `w`/`h`. Every renderer whose
//! scene has a `camera:` block can so render any frame of a dataset
//! (`hpjudge render SCENE --all-frames` renders them all).
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `transforms` | the JSON file, relative to the scene | required |
//! | `frame` | index into its `frames` | 0 |

use serde::Deserialize;
use serde_yaml::Value;

use super::SceneDoc;
use crate::camera::nerf::{parse, NerfFrame};
use crate::camera::Camera;
use crate::error::{Error, Result};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NerfSpec {
    #[serde(rename = "type")]
    _type: String,
    transforms: String,
    #[serde(default)]
    frame: usize,
}

/// The scene's nerf camera block, if its camera is one.
fn spec(doc: &SceneDoc) -> Result<Option<NerfSpec>> {
    let Some(cam) = doc.value.get("camera") else {
        return Ok(None);
    };
    if cam.get("type").and_then(Value::as_str) != Some("nerf") {
        return Ok(None);
    }
    serde_yaml::from_value(cam.clone())
        .map(Some)
        .map_err(|e| Error::invalid(format!("{}: camera", doc.at()), e.to_string()))
}

/// The frames of the scene's NeRF camera file (None: not a nerf camera).
pub fn frames(doc: &SceneDoc) -> Result<Option<Vec<NerfFrame>>> {
    let Some(s) = spec(doc)? else { return Ok(None) };
    let path = doc.resolve(&s.transforms);
    let at = path.display().to_string();
    let meta = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?;
    if meta.len() > super::MAX_YAML_BYTES {
        return Err(Error::invalid(
            &at,
            format!("{} bytes is over the limit", meta.len()),
        ));
    }
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    let dim = |k: &str| doc.value.get(k).and_then(Value::as_u64).map(|v| v as u32);
    parse(
        &text,
        &at,
        (dim("width").unwrap_or(64), dim("height").unwrap_or(64)),
    )
    .map(Some)
}

/// Replaces a nerf camera block by the `pinhole_k` camera of its frame.
pub fn expand(doc: &mut SceneDoc) -> Result<()> {
    let Some(s) = spec(doc)? else { return Ok(()) };
    let Some(all) = frames(doc)? else {
        return Ok(());
    };
    let f = all.get(s.frame).ok_or_else(|| {
        Error::invalid(
            format!("{}: camera.frame", doc.at()),
            format!(
                "{} is past the last of {} frames in {}",
                s.frame,
                all.len(),
                s.transforms
            ),
        )
    })?;
    let map = doc
        .value
        .as_mapping_mut()
        .ok_or_else(|| Error::invalid(String::new(), "a scene must be a YAML mapping"))?;
    let dims = [("width", f.width), ("height", f.height)];
    let mut size = [0u32; 2];
    for (i, (k, v)) in dims.iter().enumerate() {
        size[i] = match map.get(*k).and_then(Value::as_u64) {
            Some(n) => n as u32,
            None => {
                map.insert((*k).into(), Value::from(v.round() as u64));
                v.round() as u32
            }
        };
    }
    let Camera::Pinhole { k, c2w } = f.camera(size[0], size[1]) else {
        return Err(Error::invalid(doc.at(), "a nerf frame is a pinhole camera"));
    };
    let mut cam = serde_yaml::Mapping::new();
    cam.insert("type".into(), "pinhole_k".into());
    let kv = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0];
    cam.insert("k".into(), kv.iter().map(|&x| Value::from(x)).collect());
    cam.insert(
        "c2w".into(),
        c2w.iter().flatten().map(|&x| Value::from(x)).collect(),
    );
    map.insert("camera".into(), Value::Mapping(cam));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(dir: &std::path::Path, scene: &str) -> Result<SceneDoc> {
        std::fs::write(
            dir.join("t.json"),
            r#"{"fl_x": 50, "w": 100, "h": 80, "frames": [
              {"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]},
              {"transform_matrix": [[0,0,1,3],[0,1,0,0],[-1,0,0,0],[0,0,0,1]], "cx": 10}]}"#,
        )
        .unwrap();
        let p = dir.join("s.yaml");
        std::fs::write(&p, scene).unwrap();
        SceneDoc::load(&p, &[])
    }

    #[test]
    fn a_nerf_camera_becomes_the_pinhole_k_of_its_frame_scaled_to_the_scene() {
        let d = std::env::temp_dir().join(format!("hp-nerf-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let s = doc(
            &d,
            "renderer: rays\nwidth: 50\ncamera: {type: nerf, transforms: t.json, frame: 1}\n",
        )
        .unwrap();
        let cam = &s.value["camera"];
        assert_eq!(cam["type"].as_str(), Some("pinhole_k"));
        let k: Vec<f64> = cam["k"]
            .as_sequence()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        // width 50 of 100: fx and cx halve; height from the file (80): fy and cy stay.
        assert_eq!(k, vec![25.0, 0.0, 5.0, 0.0, 50.0, 40.0, 0.0, 0.0, 1.0]);
        assert_eq!(s.value["height"].as_u64(), Some(80));
        assert_eq!(cam["c2w"][3].as_f64(), Some(3.0));
        super::super::validate(&s).unwrap();
        let e = doc(
            &d,
            "renderer: rays\ncamera: {type: nerf, transforms: t.json, frame: 2}\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("past the last of 2 frames"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
