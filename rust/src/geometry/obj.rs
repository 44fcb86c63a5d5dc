//! Wavefront OBJ loading through tobj: polygons are triangulated, every OBJ object or group
//! becomes one object of the mesh, and an MTL diffuse colour (if any) becomes a Lambert
//! albedo (Phong when the MTL gives a specular colour and exponent).

use std::path::Path;

use crate::bsdf::Material;
use crate::error::{Error, Result};

use super::mesh::Mesh;

fn clamp_color(c: [f32; 3]) -> [f32; 3] {
    c.map(|v| {
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    })
}

/// The material an MTL entry maps to: Lambert from `Kd`, or normalised Phong when `Ks` and
/// `Ns` are present; colours are clamped to [0, 1] and scaled so that `kd + ks <= 1`.
fn material_from_mtl(m: &tobj::Material) -> Material {
    let kd = clamp_color(m.diffuse.unwrap_or([0.7; 3]));
    match (m.specular, m.shininess) {
        (Some(ks), Some(ns)) if ks.iter().any(|&v| v > 0.0) && ns.is_finite() => {
            let ks = clamp_color(ks);
            let total = (0..3).map(|i| kd[i] + ks[i]).fold(1.0f32, f32::max);
            let kd = kd.map(|v| v / total);
            let ks = ks.map(|v| v / total);
            Material::phong(kd, ks, ns.clamp(1.0, 1e4)).unwrap_or(Material::Lambert { albedo: kd })
        }
        _ => Material::Lambert { albedo: kd },
    }
}

/// What tobj does not check: the text is UTF-8, and every face has at least three
/// vertices (tobj turns `f 1 2` into a degenerate triangle). The error gives the line.
fn check_text(path: &Path, bytes: &[u8]) -> Result<()> {
    let bad = |reason: String| Error::Parse {
        path: path.to_owned(),
        reason,
    };
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        bad(format!("line {line}: not UTF-8 text (an OBJ file is text)"))
    })?;
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() == Some("f") {
            let n = words.take_while(|w| !w.starts_with('#')).count();
            if n < 3 {
                return Err(bad(format!(
                    "line {}: a face needs at least 3 vertices, got {n}",
                    i + 1
                )));
            }
        }
    }
    Ok(())
}

/// Loads an OBJ file. A missing file, a directory, text that is not UTF-8, a face of fewer
/// than three vertices, a malformed file or a face that indexes a missing vertex is an
/// error naming the path (and the line where we know it).
pub fn load_obj(path: &Path) -> Result<Mesh> {
    // Read it ourselves first: tobj reports every open failure the same way.
    let io = |source: std::io::Error| Error::Io {
        path: path.to_owned(),
        source,
    };
    if std::fs::metadata(path).map_err(io)?.is_dir() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "is a directory, not an OBJ file",
        )));
    }
    check_text(path, &std::fs::read(path).map_err(io)?)?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let (models, materials) = tobj::load_obj(path, &options).map_err(|e| Error::Parse {
        path: path.to_owned(),
        reason: format!("not a valid OBJ file ({e})"),
    })?;
    // A missing or broken MTL library leaves the default material, as most viewers do.
    let materials = materials.unwrap_or_default();
    let mut mesh = Mesh::new();
    for model in &models {
        let m = &model.mesh;
        let vertices: Vec<[f32; 3]> = m
            .positions
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect();
        let faces: Vec<[i64; 3]> = m
            .indices
            .chunks_exact(3)
            .map(|f| [f[0] as i64, f[1] as i64, f[2] as i64])
            .collect();
        let material = m
            .material_id
            .and_then(|i| materials.get(i))
            .map(material_from_mtl)
            .unwrap_or_default();
        let name = (!model.name.is_empty()).then(|| model.name.clone());
        mesh.add_indexed(&vertices, &faces, material, name)
            .map_err(|e| Error::Parse {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("viscache-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn groups_become_objects_and_quads_triangulate() {
        let p = write(
            "two.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\no first\nf 1 2 3 4\no second\nf 1 2 3\n",
        );
        let m = load_obj(&p).unwrap();
        assert_eq!(m.num_triangles(), 3);
        assert_eq!(m.objects.len(), 2);
        assert_eq!(m.objects[0].name, "first");
        assert_eq!(m.object_ids, vec![0, 0, 1]);
    }

    #[test]
    fn errors_name_the_path() {
        let missing = std::env::temp_dir().join("viscache-no-such-file.obj");
        let e = load_obj(&missing).unwrap_err().to_string();
        assert!(e.contains("viscache-no-such-file.obj"), "{e}");
        let p = write("bad.obj", "v 0 0 0\nv 1 0 0\nf 1 2 9\n");
        let e = load_obj(&p).unwrap_err().to_string();
        assert!(e.contains("bad.obj"), "{e}");
        let p = write("garbage.obj", "v 0 zero 0\nf 1 1 1\n");
        assert!(load_obj(&p)
            .unwrap_err()
            .to_string()
            .contains("garbage.obj"));
        let p = write(
            "edge.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 # an edge\n",
        );
        let e = load_obj(&p).unwrap_err().to_string();
        assert!(
            e.ends_with("line 5: a face needs at least 3 vertices, got 2"),
            "{e}"
        );
        let p = write("latin1.obj", "v 0 0 0\n");
        std::fs::write(&p, b"v 0 0 0\no caf\xe9\n").unwrap();
        let e = load_obj(&p).unwrap_err().to_string();
        assert!(
            e.ends_with("line 2: not UTF-8 text (an OBJ file is text)"),
            "{e}"
        );
        let e = load_obj(p.parent().unwrap()).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
    }

    /// Bounded fuzzing: 600 damaged OBJ files load or fail with an error naming the file;
    /// none panics.
    #[test]
    fn damaged_files_never_panic() {
        let good = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\no quad\n\
                     f 1/1/1 2/1/1 3/1/1 4/1/1\ng tri\nf 1 3 4\nusemtl none\nf -1 -2 -3\n";
        let mut refused = 0;
        for k in 0..600 {
            let p = write("fuzz.obj", "");
            std::fs::write(&p, crate::testing::damaged(good, k, 2)).unwrap();
            if let Err(e) = load_obj(&p) {
                assert!(e.to_string().contains("fuzz.obj"), "{e}");
                refused += 1;
            }
        }
        assert!(refused > 100, "{refused}");
    }
}
