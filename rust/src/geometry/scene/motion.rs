//! Rigid motion of objects: rest poses kept, transforms applied to them, BVH refits.

use std::sync::OnceLock;

use glam::{Affine3A, Vec3};

use super::Scene;
use crate::error::{Error, Result};
use crate::geometry::bvh::BvhUpdate;
use crate::geometry::mesh::Bounds;

/// A moved object's rest pose and the transform applied to it.
#[derive(Clone, Debug)]
pub(super) struct Posed {
    pub(super) rest: Vec<[Vec3; 3]>,
    pub(super) transform: Affine3A,
    /// Bounds of the object as it is now.
    pub(super) bounds: Bounds,
}

/// Rigid motion of objects (animation).
impl Scene {
    /// Object `object`, or an error naming `object`.
    pub(super) fn object(&self, object: u32) -> Result<&crate::geometry::Object> {
        self.mesh.objects.get(object as usize).ok_or_else(|| {
            Error::invalid(
                "object",
                format!("no object {object} in a scene of {}", self.num_objects()),
            )
        })
    }

    /// Places object `object` at `transform` applied to its rest pose (its triangles as
    /// they were before the first call), and refits a built BVH ([`BvhUpdate::Refit`]).
    /// The identity restores the rest pose bit for bit. See
    /// [`Scene::set_object_transform_with`].
    pub fn set_object_transform(&mut self, object: u32, transform: Affine3A) -> Result<()> {
        self.set_object_transform_with(object, transform, BvhUpdate::Refit)
    }

    /// [`Scene::set_object_transform`] with the BVH update chosen by `update`. The first
    /// move of an object drops the BVH whatever `update` says: the next build gives the
    /// object a subtree of its own ([`Scene::bvh`]), which later refits keep as good as a
    /// rebuild. A refit that cannot match a rebuild (a triangle becomes degenerate or stops
    /// being so, say) falls back to a rebuild. Bounds, and the object's area light if it
    /// emits, follow the object. An unknown `object` or a non-finite `transform`, or one
    /// that maps a vertex out of the `f32` range, is an error naming the argument, and the
    /// scene is unchanged.
    pub fn set_object_transform_with(
        &mut self,
        object: u32,
        transform: Affine3A,
        update: BvhUpdate,
    ) -> Result<()> {
        let obj = self.object(object)?;
        let range = obj.first_triangle as usize..(obj.first_triangle + obj.num_triangles) as usize;
        if !transform.is_finite() {
            return Err(Error::invalid(
                "transform",
                format!("must be finite, got {transform:?}"),
            ));
        }
        let rest = match self.posed.get(&object) {
            Some(p) => &p.rest[..],
            None => &self.mesh.triangles[range.clone()],
        };
        let moved: Vec<[Vec3; 3]> = rest
            .iter()
            .map(|t| t.map(|v| transform.transform_point3(v)))
            .collect();
        if moved.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "transform",
                format!("maps vertices of object {object} out of the f32 range"),
            ));
        }
        let light = match self.lights.iter().position(|l| l.object == object) {
            Some(i) => {
                let light = self.lights[i].moved(moved.clone()).map_err(|e| {
                    Error::invalid("transform", format!("leaves the area light unusable: {e}"))
                })?;
                Some((i, light))
            }
            None => None,
        };
        // Validated: from here on nothing fails.
        if let Some((i, light)) = light {
            self.lights[i] = light;
        }
        let first_move = !self.posed.contains_key(&object);
        if first_move {
            let rest = self.mesh.triangles[range.clone()].to_vec();
            let bounds = Bounds::of_triangles(&rest);
            let posed = Posed {
                rest,
                transform: Affine3A::IDENTITY,
                bounds,
            };
            self.posed.insert(object, posed);
            self.still_bounds = self.bounds_of_still_objects();
        }
        let posed = self.posed.get_mut(&object).expect("inserted above");
        posed.transform = transform;
        posed.bounds = Bounds::of_triangles(&moved);
        self.mesh.triangles[range.clone()].copy_from_slice(&moved);
        self.bounds = (self.posed.values()).fold(self.still_bounds, |b, p| b.union(&p.bounds));
        match update {
            BvhUpdate::Refit if !first_move => {
                let refit = match self.bvh.get_mut() {
                    Some(bvh) => bvh.refit(&self.mesh, range),
                    None => true,
                };
                if !refit {
                    self.bvh = OnceLock::new();
                    self.bvh();
                }
            }
            _ => self.bvh = OnceLock::new(),
        }
        Ok(())
    }

    /// A 64-bit digest of the scene as it is posed now: [`Scene::geometry_fingerprint`]
    /// and every object's transform other than the identity. Whatever was computed from
    /// first hits (a [`crate::camera::GBuffer`]) holds for this digest only.
    pub fn pose_fingerprint(&self) -> u64 {
        let mut h = super::Digest::default();
        h.word(self.geometry_fingerprint());
        for (object, posed) in &self.posed {
            if posed.transform != Affine3A::IDENTITY {
                h.word(*object as u64);
                for v in posed.transform.to_cols_array() {
                    h.word(v.to_bits() as u64);
                }
            }
        }
        h.finish()
    }

    /// Gives object `object` another material. Geometry, the BVH and fingerprints are
    /// unchanged (records and G-buffers stay valid); an unknown `object` is an error
    /// naming it.
    pub fn set_material(&mut self, object: u32, material: crate::bsdf::Material) -> Result<()> {
        self.object(object)?;
        self.mesh.objects[object as usize].material = material;
        Ok(())
    }

    /// True once object `object` has been given a transform (false for unknown objects).
    pub fn is_posed(&self, object: u32) -> bool {
        self.posed.contains_key(&object)
    }

    /// The transform last given to object `object` (the identity if it never moved).
    pub fn object_transform(&self, object: u32) -> Result<Affine3A> {
        self.object(object)?;
        Ok(self
            .posed
            .get(&object)
            .map_or(Affine3A::IDENTITY, |p| p.transform))
    }

    /// Bounds of object `object`'s vertices as it is now (empty for an empty object).
    pub fn object_bounds(&self, object: u32) -> Result<Bounds> {
        self.object(object)?;
        Ok(match self.posed.get(&object) {
            Some(p) => p.bounds,
            None => Bounds::of_triangles(self.triangles_of(object as usize)),
        })
    }
}
