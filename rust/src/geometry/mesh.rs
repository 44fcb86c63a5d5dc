//! Triangle soup with per-triangle object ids. Every object carries a name and a material;
//! triangles are stored as three world-space `f32` vertices so that a BVH, an exporter or a
//! brute-force test can read them without indirection.

use glam::Vec3;

use crate::bsdf::Material;
use crate::error::{Error, Result};

/// One object of a mesh: a contiguous run of triangles sharing a material.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    /// Name given at insertion (OBJ object/group name, trimesh node name, or `object<i>`).
    pub name: String,
    /// The object's material.
    pub material: Material,
    /// Index of the object's first triangle in [`Mesh::triangles`].
    pub first_triangle: u32,
    /// Number of triangles of the object (may be 0).
    pub num_triangles: u32,
}

impl Object {
    /// Indices of the object's triangles in [`Mesh::triangles`].
    pub fn triangle_range(&self) -> std::ops::Range<usize> {
        self.first_triangle as usize..(self.first_triangle + self.num_triangles) as usize
    }
}

/// Axis-aligned bounds; the empty box has `min = +inf`, `max = -inf`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: Vec3,
    pub max: Vec3,
}

impl Bounds {
    /// The empty box, neutral for [`Bounds::grow`].
    pub const EMPTY: Bounds = Bounds {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// Extends the box to contain `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// The smallest box holding both.
    pub fn union(&self, other: &Bounds) -> Bounds {
        Bounds {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Bounds of the vertices of `triangles`.
    pub fn of_triangles(triangles: &[[Vec3; 3]]) -> Bounds {
        let mut b = Bounds::EMPTY;
        for t in triangles {
            for v in t {
                b.grow(*v);
            }
        }
        b
    }

    /// True when nothing has been added.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    /// Largest side length (0 for the empty box).
    pub fn extent(&self) -> f32 {
        if self.is_empty() {
            0.0
        } else {
            (self.max - self.min).max_element()
        }
    }

    /// Largest absolute coordinate of the box (0 for the empty box).
    pub fn max_abs(&self) -> f32 {
        if self.is_empty() {
            0.0
        } else {
            self.min.abs().max(self.max.abs()).max_element()
        }
    }
}

/// A triangle soup: `triangles[i]` belongs to `objects[object_ids[i]]`.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// World-space vertices of each triangle.
    pub triangles: Vec<[Vec3; 3]>,
    /// Object index of each triangle.
    pub object_ids: Vec<u32>,
    /// Objects in insertion order; object ids index this.
    pub objects: Vec<Object>,
}

/// Checks that every component is finite; the error names `name` and the first bad row.
pub fn check_finite(name: &str, rows: &[[f32; 3]]) -> Result<()> {
    match rows.iter().position(|r| r.iter().any(|v| !v.is_finite())) {
        None => Ok(()),
        Some(i) => Err(Error::invalid(
            name,
            format!("row {i} is not finite: {:?}", rows[i]),
        )),
    }
}

impl Mesh {
    /// An empty mesh.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of triangles.
    pub fn num_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Bounds of all vertices (degenerate triangles included).
    pub fn bounds(&self) -> Bounds {
        Bounds::of_triangles(&self.triangles)
    }

    /// Adds an indexed triangle mesh as a new object and returns its id.
    ///
    /// `vertices` must be finite; `faces` index into them (`0 <= index < vertices.len()`).
    /// Nothing is added when validation fails.
    pub fn add_indexed(
        &mut self,
        vertices: &[[f32; 3]],
        faces: &[[i64; 3]],
        material: Material,
        name: Option<String>,
    ) -> Result<u32> {
        check_finite("vertices", vertices)?;
        let n = vertices.len() as i64;
        if let Some((i, f)) = faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&k| k < 0 || k >= n))
        {
            return Err(Error::invalid(
                "faces",
                format!("face {i} = {f:?} indexes outside the {n} vertices"),
            ));
        }
        // The mesh grows by the faces' triangles and object ids: reserved first, so that a
        // size that cannot be met is an error (MemoryError), not an abort part-way.
        let oom = |bytes| crate::alloc::out_of_memory("faces", bytes);
        self.triangles
            .try_reserve(faces.len())
            .map_err(|_| oom(crate::alloc::bytes_of::<[Vec3; 3]>(faces.len())))?;
        self.object_ids
            .try_reserve(faces.len())
            .map_err(|_| oom(crate::alloc::bytes_of::<u32>(faces.len())))?;
        let tris = faces
            .iter()
            .map(|f| f.map(|k| Vec3::from(vertices[k as usize])));
        self.add_triangles(tris, material, name)
    }

    /// Adds explicit triangles as a new object and returns its id. Vertices must be finite.
    pub fn add_triangles(
        &mut self,
        triangles: impl IntoIterator<Item = [Vec3; 3]>,
        material: Material,
        name: Option<String>,
    ) -> Result<u32> {
        let id = self.objects.len();
        if id >= i32::MAX as usize {
            return Err(Error::invalid("scene", "too many objects"));
        }
        let first = self.triangles.len();
        self.triangles.extend(triangles);
        let added = self.triangles.len() - first;
        if let Some(i) = self.triangles[first..]
            .iter()
            .position(|t| t.iter().any(|v| !v.is_finite()))
        {
            self.triangles.truncate(first);
            return Err(Error::invalid(
                "vertices",
                format!("triangle {i} has a non-finite vertex"),
            ));
        }
        if self.triangles.len() >= i32::MAX as usize {
            self.triangles.truncate(first);
            return Err(Error::invalid("faces", "too many triangles"));
        }
        self.object_ids
            .extend(std::iter::repeat_n(id as u32, added));
        self.objects.push(Object {
            name: name.unwrap_or_else(|| format!("object{id}")),
            material,
            first_triangle: first as u32,
            num_triangles: added as u32,
        });
        Ok(id as u32)
    }

    /// Appends every object of `other`, keeping names and materials.
    pub fn append(&mut self, other: &Mesh) {
        let offset = self.objects.len() as u32;
        let first = self.triangles.len() as u32;
        self.triangles.extend_from_slice(&other.triangles);
        self.object_ids
            .extend(other.object_ids.iter().map(|&o| o + offset));
        self.objects.extend(other.objects.iter().map(|o| Object {
            first_triangle: o.first_triangle + first,
            ..o.clone()
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn add_indexed_validates_before_changing_anything() {
        let mut m = Mesh::new();
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert_eq!(
            m.add_indexed(&v, &[[0, 1, 2]], Material::DEFAULT, None)
                .unwrap(),
            0
        );
        let e = m
            .add_indexed(&v, &[[0, 1, 3]], Material::DEFAULT, None)
            .unwrap_err();
        assert!(e.to_string().starts_with("faces"), "{e}");
        let e = m
            .add_indexed(&v, &[[0, -1, 2]], Material::DEFAULT, None)
            .unwrap_err();
        assert!(e.to_string().contains("face 0"), "{e}");
        let bad = [[0.0, f32::NAN, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let e = m
            .add_indexed(&bad, &[[0, 1, 2]], Material::DEFAULT, None)
            .unwrap_err();
        assert!(e.to_string().starts_with("vertices"), "{e}");
        assert_eq!(m.num_triangles(), 1);
        assert_eq!(m.objects.len(), 1);
        assert_eq!(m.object_ids, vec![0]);
    }

    #[test]
    fn empty_bounds_and_objects() {
        let mut m = Mesh::new();
        assert!(m.bounds().is_empty());
        assert_eq!(m.bounds().extent(), 0.0);
        let id = m
            .add_indexed(&[], &[], Material::DEFAULT, Some("e".into()))
            .unwrap();
        assert_eq!(id, 0);
        assert_eq!(m.objects[0].num_triangles, 0);
        assert!(m.bounds().is_empty());
    }
}
