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

/// What tobj does not report by line (or at all): the text is UTF-8; a vertex has three
/// finite coordinates (four with `w`, six with a colour); a face has at least three
/// vertices (tobj turns `f 1 2` into a degenerate triangle), each an index that is an
/// integer, not 0, and names a vertex (texture coordinate, normal) the file has; negative
/// indices count back from the element before the face. The error gives the line.
fn check_text(path: &Path, bytes: &[u8]) -> Result<()> {
    let bad = |line: usize, reason: String| Error::Parse {
        path: path.to_owned(),
        reason: format!("line {line}: {reason}"),
    };
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        bad(line, "not UTF-8 text (an OBJ file is text)".into())
    })?;
    // Positive indices may point forward (tobj resolves them once the file is read), so
    // they are judged against the file's totals; negative ones against the count so far.
    let mut total = [0usize; 3];
    for line in text.lines() {
        match line.split_whitespace().next() {
            Some("v") => total[0] += 1,
            Some("vt") => total[1] += 1,
            Some("vn") => total[2] += 1,
            _ => {}
        }
    }
    let kinds = ["vertex", "texture coordinate", "normal"];
    let plural = ["vertices", "texture coordinates", "normals"];
    let mut seen = [0usize; 3];
    for (i, line) in text.lines().enumerate() {
        let number = i + 1;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let values: Vec<&str> = words.take_while(|w| !w.starts_with('#')).collect();
                if !matches!(values.len(), 3 | 4 | 6) {
                    return Err(bad(
                        number,
                        format!(
                            "a vertex needs 3 coordinates (4 with w, 6 with a colour), got {}",
                            values.len()
                        ),
                    ));
                }
                for w in &values[..3] {
                    match w.parse::<f32>() {
                        Ok(x) if x.is_finite() => {}
                        Ok(_) => {
                            return Err(bad(number, format!("vertex coordinate {w} is not finite")))
                        }
                        Err(_) => {
                            return Err(bad(
                                number,
                                format!("vertex coordinate {w:?} is not a number"),
                            ))
                        }
                    }
                }
                seen[0] += 1;
            }
            Some("vt") => seen[1] += 1,
            Some("vn") => seen[2] += 1,
            Some("f") => {
                let corners: Vec<&str> = words.take_while(|w| !w.starts_with('#')).collect();
                if corners.len() < 3 {
                    return Err(bad(
                        number,
                        format!("a face needs at least 3 vertices, got {}", corners.len()),
                    ));
                }
                for corner in corners {
                    let parts: Vec<&str> = corner.split('/').collect();
                    if parts.len() > 3 || parts[0].is_empty() {
                        return Err(bad(
                            number,
                            format!("face vertex {corner:?} is not v, v/vt, v//vn or v/vt/vn"),
                        ));
                    }
                    for (k, part) in parts.iter().enumerate() {
                        if part.is_empty() {
                            continue;
                        }
                        let index: i64 = part.parse().map_err(|_| {
                            bad(
                                number,
                                format!("{} index {part:?} is not an integer in range", kinds[k]),
                            )
                        })?;
                        let ok = match index {
                            0 => false,
                            i if i > 0 => i as u64 <= total[k] as u64,
                            i => i.unsigned_abs() <= seen[k] as u64,
                        };
                        if !ok {
                            let have = if index < 0 { seen[k] } else { total[k] };
                            let before = if index < 0 { " before this line" } else { "" };
                            return Err(bad(
                                number,
                                format!(
                                    "{} index {index} does not exist (OBJ indices start at 1; \
                                     the file has {have} {}{before})",
                                    kinds[k], plural[k]
                                ),
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Loads an OBJ file. A missing file, a directory, text that is not UTF-8, a malformed
/// vertex, a face of fewer than three vertices or one that indexes a missing vertex, a
/// malformed file, or a file without a single triangle is an error naming the path (and
/// the line where there is one).
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
    // Random text or a file of vertices only parses to nothing: that is no scene.
    if mesh.num_triangles() == 0 {
        return Err(Error::Parse {
            path: path.to_owned(),
            reason: "no faces: the file holds no triangles (is it an OBJ file?)".into(),
        });
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

    /// Every malformed line is refused with its line number, and a file without a triangle
    /// (empty, vertices only, or random printable text) is refused naming the file.
    #[test]
    fn malformed_lines_and_files_without_faces_are_refused() {
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        let cases = [
            ("v 1\n".to_string(), "line 1: a vertex needs 3 coordinates"),
            (
                format!("{tri}v 1 2 x\n"),
                "line 4: vertex coordinate \"x\" is not a number",
            ),
            (
                format!("{tri}v nan 0 0\n"),
                "line 4: vertex coordinate nan is not finite",
            ),
            (
                format!("{tri}v 1e39 0 0\n"),
                "line 4: vertex coordinate 1e39 is not finite",
            ),
            (
                format!("{tri}f 1 2 3\nf 1 2"),
                "line 5: a face needs at least 3 vertices, got 2",
            ),
            (
                format!("{tri}f 1\n"),
                "line 4: a face needs at least 3 vertices, got 1",
            ),
            (
                format!("{tri}f 1 2 99999999999999999999\n"),
                "line 4: vertex index \"99999999999999999999\" is not an integer in range",
            ),
            (
                format!("{tri}f 1 2 x\n"),
                "line 4: vertex index \"x\" is not an integer",
            ),
            (
                format!("{tri}f 0 1 2\n"),
                "line 4: vertex index 0 does not exist",
            ),
            (
                format!("{tri}f 1 2 4\n"),
                "line 4: vertex index 4 does not exist",
            ),
            (
                format!("v 0 0 0\nf -1 -2 -3\n{tri}"),
                "line 2: vertex index -2 does not exist (OBJ indices start at 1; the file has \
                 1 vertices before this line)",
            ),
            (
                format!("{tri}vt 0 0\nf 1/2 2/1 3/1\n"),
                "line 5: texture coordinate index 2",
            ),
            (
                format!("{tri}f 1//1 2//1 3//1\n"),
                "line 4: normal index 1 does not exist",
            ),
            (
                format!("{tri}f 1/1/1/1 2 3\n"),
                "line 4: face vertex \"1/1/1/1\" is not",
            ),
            (String::new(), "no faces"),
            (tri.to_string(), "no faces"),
            (
                "x7 %$ q\n\t!!}{ 'w\nvt 1 1\nusemtl ~\n".to_string(),
                "no faces",
            ),
        ];
        for (k, (text, expect)) in cases.iter().enumerate() {
            let p = write(&format!("case{k}.obj"), text);
            let e = load_obj(&p).unwrap_err().to_string();
            assert!(
                e.starts_with(&p.display().to_string()) && e.contains(expect),
                "case {k}: {e}"
            );
        }
        // Forward references stay allowed (tobj resolves them), as do w and colours.
        let p = write("forward.obj", "f 1 2 3\nv 0 0 0\nv 1 0 0 2\nv 0 1 0\n");
        assert_eq!(load_obj(&p).unwrap().num_triangles(), 1);
        let p = write(
            "colours.obj",
            "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n",
        );
        assert_eq!(load_obj(&p).unwrap().num_triangles(), 1);
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
