//! Area lights: emitting objects of the scene.

use glam::Vec3;

use super::{Scene, SurfaceHit};
use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::geometry::mesh::check_finite;
use crate::lights::area::{AreaLight, EmissionTexture};

/// Area lights. Emitters are objects of the mesh (they occlude and can be hit like any
/// other geometry); the scene keeps the [`AreaLight`] of each.
impl Scene {
    /// Adds a one-sided emitter over a triangle (3 vertices) or a quad (4 vertices, in order
    /// around its border) as a new, black object; it emits on the side of the winding normal
    /// `(v1 - v0) x (v2 - v0)`. Returns the object id. On error the scene is unchanged.
    pub fn add_area_light(
        &mut self,
        vertices: &[[f32; 3]],
        radiance: [f32; 3],
        name: Option<String>,
    ) -> Result<u32> {
        let faces: &[[i64; 3]] = match vertices.len() {
            3 => &[[0, 1, 2]],
            4 => &[[0, 1, 2], [0, 2, 3]],
            n => {
                return Err(Error::invalid(
                    "vertices",
                    format!("an area light is a triangle (3 vertices) or a quad (4), got {n}"),
                ))
            }
        };
        check_finite("vertices", vertices)?;
        let triangles = faces
            .iter()
            .map(|f| f.map(|i| Vec3::from_array(vertices[i as usize])))
            .collect();
        let object = self.num_objects() as u32;
        let light = AreaLight::new(object, triangles, radiance)?;
        let black = Material::Lambert { albedo: [0.0; 3] };
        let name = name.or_else(|| Some(format!("area_light{}", self.lights.len())));
        let id = self.add_indexed(vertices, faces, black, name)?;
        debug_assert_eq!(id, object);
        self.lights.push(light);
        Ok(id)
    }

    /// Makes the existing object `object` emit `radiance` from the winding side of its
    /// triangles (e.g. a lamp modelled as geometry). Fails if it already emits.
    pub fn set_emitter(&mut self, object: u32, radiance: [f32; 3]) -> Result<()> {
        let obj = self.object(object)?;
        if self.emitter(object).is_some() {
            return Err(Error::invalid(
                "object",
                format!("object {object} already emits"),
            ));
        }
        let first = obj.first_triangle as usize;
        let triangles = self.mesh.triangles[first..first + obj.num_triangles as usize].to_vec();
        self.lights
            .push(AreaLight::new(object, triangles, radiance)?);
        Ok(())
    }

    /// Gives the emitting object `object` another `radiance` (its triangles, and so how
    /// it is sampled, stay). Fails, leaving the scene unchanged, if it does not emit.
    pub fn set_emission(&mut self, object: u32, radiance: [f32; 3]) -> Result<()> {
        let i = self.emitter_index(object)?;
        self.lights[i] = self.lights[i].with_radiance(radiance)?;
        Ok(())
    }

    /// Gives the emitting quad `object` an RGB `texture` over its `uv` square (radiance
    /// becomes its radiance times the texel; [`EmissionTexture`]), or removes it with
    /// `None`. Sampling stays by area. Fails, leaving the scene unchanged, if the object
    /// does not emit or is not a quad.
    pub fn set_emission_texture(
        &mut self,
        object: u32,
        texture: Option<EmissionTexture>,
    ) -> Result<()> {
        let i = self.emitter_index(object)?;
        self.lights[i] = self.lights[i].clone().with_texture(texture)?;
        Ok(())
    }

    /// Index in [`Self::area_lights`] of the light of object `object`; an error naming
    /// `object` if it does not exist or does not emit.
    fn emitter_index(&self, object: u32) -> Result<usize> {
        self.object(object)?;
        self.lights
            .iter()
            .position(|l| l.object == object)
            .ok_or_else(|| {
                Error::invalid(
                    "object",
                    format!("object {object} does not emit (see set_emitter)"),
                )
            })
    }

    /// The scene's area lights, in the order they were added.
    pub fn area_lights(&self) -> &[AreaLight] {
        &self.lights
    }

    /// The light of object `object`, if it emits.
    pub fn emitter(&self, object: u32) -> Option<&AreaLight> {
        self.lights.iter().find(|l| l.object == object)
    }

    /// Radiance leaving the surface at `hit` towards `towards_viewer` if it is an emitter.
    pub fn emitted(&self, hit: &SurfaceHit, towards_viewer: Vec3) -> Vec3 {
        match self.emitter(hit.obj) {
            Some(light) => {
                let first = self.mesh.objects[hit.obj as usize].first_triangle;
                light.emitted((hit.prim - first) as usize, hit.position, towards_viewer)
            }
            None => Vec3::ZERO,
        }
    }
}
