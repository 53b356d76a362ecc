//! Triangle meshes for surface voxelisation: OBJ (`tobj`) and PLY
//! (`ply-rs-bw`) reading, positions only, polygons fanned into triangles,
//! and SCENES.md's placement (`bunny.yaml`): the centre of the mesh's
//! axis-aligned bounding box goes to the origin, then a uniform scale makes
//! its longest side 1.8; no rotation.

use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

use crate::error::{Error, Result};

/// Triangles in world coordinates (f64; every vertex finite).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub tris: Vec<[[f64; 3]; 3]>,
}

/// Longest side of the placed mesh's bounding box (SCENES.md).
pub const PLACED_EXTENT: f64 = 1.8;

impl Mesh {
    /// Reads `path` by its extension (`.obj` or `.ply`).
    pub fn load(path: &Path) -> Result<Mesh> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        let mesh = match ext.as_deref() {
            Some("obj") => load_obj(path)?,
            Some("ply") => load_ply(path)?,
            _ => {
                return Err(Error::invalid(
                    path.display().to_string(),
                    "a mesh must be an .obj or .ply file",
                ))
            }
        };
        if mesh.tris.is_empty() {
            return Err(Error::invalid(path.display().to_string(), "no triangles"));
        }
        if let Some(i) = mesh
            .tris
            .iter()
            .position(|t| t.iter().flatten().any(|x| !x.is_finite()))
        {
            return Err(Error::invalid(
                path.display().to_string(),
                format!("triangle {i} has a non-finite vertex"),
            ));
        }
        Ok(mesh)
    }

    /// Axis-aligned bounding box (min, max).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in self.tris.iter().flatten() {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        (lo, hi)
    }

    /// SCENES.md placement: bounding-box centre to the origin, longest side
    /// [`PLACED_EXTENT`]. A mesh with no extent is refused.
    pub fn placed(&self) -> Result<Mesh> {
        let (lo, hi) = self.bounds();
        let ext = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        if !(ext > 0.0 && ext.is_finite()) {
            return Err(Error::invalid("mesh", "its bounding box has no extent"));
        }
        let c = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
        let s = PLACED_EXTENT / ext;
        Ok(Mesh {
            tris: self
                .tris
                .iter()
                .map(|t| t.map(|p| [0, 1, 2].map(|a| (p[a] - c[a]) * s)))
                .collect(),
        })
    }
}

fn fan(pos: &[[f64; 3]], poly: &[usize], at: &str, tris: &mut Vec<[[f64; 3]; 3]>) -> Result<()> {
    if let Some(&bad) = poly.iter().find(|&&i| i >= pos.len()) {
        return Err(Error::invalid(
            at,
            format!("vertex index {bad} with {} vertices", pos.len()),
        ));
    }
    for k in 1..poly.len().saturating_sub(1) {
        tris.push([pos[poly[0]], pos[poly[k]], pos[poly[k + 1]]]);
    }
    Ok(())
}

fn load_obj(path: &Path) -> Result<Mesh> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj(path, &opts)
        .map_err(|e| Error::invalid(path.display().to_string(), format!("OBJ: {e}")))?;
    let mut tris = Vec::new();
    for m in &models {
        let pos: Vec<[f64; 3]> = m
            .mesh
            .positions
            .chunks_exact(3)
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect();
        let at = format!("{} object `{}`", path.display(), m.name);
        for f in m.mesh.indices.chunks_exact(3) {
            fan(
                &pos,
                &f.iter().map(|&i| i as usize).collect::<Vec<_>>(),
                &at,
                &mut tris,
            )?;
        }
    }
    Ok(Mesh { tris })
}

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Float(x) => x as f64,
        Property::Double(x) => x,
        Property::Char(x) => x as f64,
        Property::UChar(x) => x as f64,
        Property::Short(x) => x as f64,
        Property::UShort(x) => x as f64,
        Property::Int(x) => x as f64,
        Property::UInt(x) => x as f64,
        _ => return None,
    })
}

fn index_list(p: &Property) -> Option<Vec<usize>> {
    fn conv<T: Copy + TryInto<usize>>(v: &[T]) -> Option<Vec<usize>> {
        v.iter().map(|&x| x.try_into().ok()).collect()
    }
    match p {
        Property::ListChar(v) => conv(v),
        Property::ListUChar(v) => conv(v),
        Property::ListShort(v) => conv(v),
        Property::ListUShort(v) => conv(v),
        Property::ListInt(v) => conv(v),
        Property::ListUInt(v) => conv(v),
        _ => None,
    }
}

fn load_ply(path: &Path) -> Result<Mesh> {
    let at = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut r = std::io::BufReader::new(f);
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut r)
        .map_err(|e| Error::invalid(at.clone(), format!("PLY: {e}")))?;
    let get = |name: &str| ply.payload.get(name).map(|v| v.as_slice()).unwrap_or(&[]);
    let mut pos = Vec::new();
    for (i, v) in get("vertex").iter().enumerate() {
        let c = ["x", "y", "z"].map(|k| v.get(k).and_then(scalar));
        let [Some(x), Some(y), Some(z)] = c else {
            return Err(Error::invalid(
                format!("{at} vertex {i}"),
                "needs numeric x, y and z",
            ));
        };
        pos.push([x, y, z]);
    }
    let mut tris = Vec::new();
    for (i, f) in get("face").iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(index_list);
        let Some(list) = list else {
            return Err(Error::invalid(
                format!("{at} face {i}"),
                "needs a vertex_indices list of non-negative integers",
            ));
        };
        fan(&pos, &list, &format!("{at} face {i}"), &mut tris)?;
    }
    Ok(Mesh { tris })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("hp_mesh_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    const QUAD_OBJ: &str = "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nf 1 2 3 4\n";
    const QUAD_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
        property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n\
        end_header\n0 0 0\n2 0 0\n2 1 0\n0 1 0\n4 0 1 2 3\n";

    #[test]
    fn obj_and_ply_quads_read_as_the_same_two_triangles() {
        let a = Mesh::load(&write("q.obj", QUAD_OBJ)).unwrap();
        let b = Mesh::load(&write("q.ply", QUAD_PLY)).unwrap();
        assert_eq!(a.tris.len(), 2);
        assert_eq!(a, b);
        assert_eq!(
            a.tris[1],
            [[0.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
        );
    }

    #[test]
    fn placement_centres_the_box_and_makes_the_longest_side_1_8() {
        let m = Mesh::load(&write("p.obj", QUAD_OBJ))
            .unwrap()
            .placed()
            .unwrap();
        let (lo, hi) = m.bounds();
        assert_eq!((lo, hi), ([-0.9, -0.45, 0.0], [0.9, 0.45, 0.0]));
    }

    #[test]
    fn bad_files_are_refused_with_their_name() {
        let e = Mesh::load(&write("bad.obj", "v 0 0 0\nf 1 2 3\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.obj"), "{e}");
        let e = Mesh::load(&write("bad.ply", "ply\nnonsense\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.ply"), "{e}");
        let e = Mesh::load(&write("m.stl", "solid"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.stl") && e.contains(".obj"), "{e}");
        let e = Mesh::load(&write("n.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("non-finite"), "{e}");
    }
}
