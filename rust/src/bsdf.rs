//! Surface materials. This module holds the material descriptions that meshes carry; the
//! BSDF evaluation, sampling and the conservative per-cell bound B~ (CAM08 §5.5, §7) build on
//! these parameters.

use crate::error::{Error, Result};

/// A surface material. Colours are linear RGB reflectances in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Ideal diffuse reflector: f = albedo / pi.
    Lambert { albedo: [f32; 3] },
    /// Energy-normalised Phong: f = kd / pi + ks (e + 2) / (2 pi) cos^e(alpha), where alpha is
    /// the angle between the mirror direction and the outgoing direction. `kd + ks <= 1` per
    /// channel keeps it energy conserving; `exponent` lies in [1, 1e4].
    Phong {
        kd: [f32; 3],
        ks: [f32; 3],
        exponent: f32,
    },
}

impl Default for Material {
    fn default() -> Self {
        Material::DEFAULT
    }
}

fn check_color(name: &str, c: [f32; 3]) -> Result<()> {
    if c.iter().any(|v| !v.is_finite() || *v < 0.0 || *v > 1.0) {
        return Err(Error::invalid(
            name,
            format!("each channel must be finite and in [0, 1], got {c:?}"),
        ));
    }
    Ok(())
}

impl Material {
    /// A light grey diffuse material, used where none is given.
    pub const DEFAULT: Material = Material::Lambert {
        albedo: [0.7, 0.7, 0.7],
    };

    /// Lambertian material with the given albedo (each channel in [0, 1]).
    pub fn lambert(albedo: [f32; 3]) -> Result<Self> {
        check_color("albedo", albedo)?;
        Ok(Material::Lambert { albedo })
    }

    /// Normalised Phong; `kd + ks` must not exceed 1 in any channel, `exponent` in [1, 1e4].
    pub fn phong(kd: [f32; 3], ks: [f32; 3], exponent: f32) -> Result<Self> {
        check_color("kd", kd)?;
        check_color("ks", ks)?;
        if (0..3).any(|i| kd[i] + ks[i] > 1.0 + 1e-6) {
            return Err(Error::invalid(
                "ks",
                format!("kd + ks must not exceed 1 in any channel (energy conservation), got kd={kd:?} ks={ks:?}"),
            ));
        }
        if !(1.0..=1e4).contains(&exponent) {
            return Err(Error::invalid(
                "exponent",
                format!("must lie in [1, 1e4], got {exponent}"),
            ));
        }
        Ok(Material::Phong { kd, ks, exponent })
    }

    /// The diffuse colour, used for simple first-hit shading.
    pub fn base_color(&self) -> [f32; 3] {
        match *self {
            Material::Lambert { albedo } => albedo,
            Material::Phong { kd, ks, .. } => [kd[0] + ks[0], kd[1] + ks[1], kd[2] + ks[2]],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_parameter() {
        assert!(Material::lambert([0.5, 0.5, 0.5]).is_ok());
        let e = Material::lambert([1.5, 0.0, 0.0]).unwrap_err().to_string();
        assert!(e.starts_with("albedo"), "{e}");
        let e = Material::phong([0.6; 3], [0.6; 3], 10.0)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("ks"), "{e}");
        let e = Material::phong([0.1; 3], [0.1; 3], 0.5)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("exponent"), "{e}");
        assert!(Material::phong([0.1; 3], [0.1; 3], f32::NAN).is_err());
        assert!(Material::phong([0.1; 3], [0.9; 3], 1e4).is_ok());
    }
}
