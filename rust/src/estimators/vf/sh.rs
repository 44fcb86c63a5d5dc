//! VF eq. 2-3: the light of a voxel's VPLs in spherical harmonics of bands `l = 0..1`
//! ([`ORDER`] 2 of `crate::sampling::sh`, 4 coefficients per channel), for voxels the
//! gather sees from farther than `sh_range` (eq. 6, second case).
//!
//! A surface VPL of flux `Φ` whose diffuse reflectance is `ρ` emits the radiant intensity
//! `I(ω) = Φ ρ/π · max(n · ω, 0)` (W/sr). The clamped cosine is zonal about `n`, with
//! zonal coefficients `A_0 = π`, `A_1 = 2π/3` (per unit `Y_l0` normalisation
//! `√(4π/(2l+1))`), so eq. 3's projection is `c_lm = Φ ρ/π · A_l Y_lm(n)`, exact for
//! bands 0-1. Band 0 keeps the flux: `∫ I dω = √(4π) c_00 = Φ ρ`. A glossy VPL's lobe
//! is not in bands 0-1: its diffuse part `k_d` stands for it here.
//!
//! A voxel's coefficients are the sums of its VPLs' (eq. 2), seen from its flux-weighted
//! centroid (the paper: "the centroid of the virtual light sources within it"), weights
//! the VPLs' luminance.

use glam::{DVec3, Vec3};

use crate::bsdf::Material;
use crate::lights::vpl::{luminance, Vpl, VplKind};
use crate::sampling::sh;

/// Bands 0..1.
pub const ORDER: u32 = 2;
/// Coefficients per channel.
pub const COEFFS: usize = sh::coefficient_count(ORDER);

/// A voxel's light in bands 0-1 (W/sr per channel per coefficient) and where it sits.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VoxelSh {
    /// `c_k` per RGB channel, `k = l² + l + m` (`crate::sampling::sh::index`).
    pub coeffs: [DVec3; COEFFS],
    /// The VPLs' luminance-weighted centroid (world units); their mean where all are
    /// black.
    pub centroid: Vec3,
    /// The expansion as `a + b_x ω_x + b_y ω_y + b_z ω_z` (bands 0-1 are affine in the
    /// direction; the basis read off `crate::sampling::sh::eval` at the axes): `[a, b_x,
    /// b_y, b_z]`, so [`VoxelSh::intensity`] costs a dot product.
    pub affine: [DVec3; 4],
}

/// `A_l` of the clamped cosine for `l = 0, 1`.
const ZONAL: [f64; 2] = [std::f64::consts::PI, 2.0 * std::f64::consts::PI / 3.0];

/// The diffuse reflectance `ρ` a VPL's SH stands for (W/sr per W of flux at normal
/// exitance, times π): Lambert's albedo, Phong's `k_d`, 1 for an emitter; none for a map
/// direction.
pub fn diffuse_albedo(v: &Vpl) -> Option<Vec3> {
    match (v.kind, v.material) {
        (VplKind::Env | VplKind::Area { .. }, _) => None,
        (VplKind::Emitter, _) => Some(Vec3::ONE),
        (VplKind::Surface, Material::Lambert { albedo }) => Some(Vec3::from(albedo)),
        (VplKind::Surface, Material::Phong { kd, .. }) => Some(Vec3::from(kd)),
    }
}

/// Eq. 3 for one VPL: `c_lm = Φ ρ/π · A_l Y_lm(n)` (module docs); zero for a map
/// direction.
pub fn project_vpl(v: &Vpl) -> [DVec3; COEFFS] {
    let mut out = [DVec3::ZERO; COEFFS];
    let Some(rho) = diffuse_albedo(v) else {
        return out;
    };
    let s = (v.flux * rho).as_dvec3() * std::f64::consts::FRAC_1_PI;
    let mut y = [0.0f64; COEFFS];
    sh::eval(ORDER, v.normal.as_dvec3().normalize(), &mut y);
    for (k, c) in out.iter_mut().enumerate() {
        let l = if k == 0 { 0 } else { 1 };
        *c = s * (ZONAL[l] * y[k]);
    }
    out
}

/// Eq. 2: the sum of `vpls`' projections and their centroid.
pub fn project_voxel<'a>(vpls: impl IntoIterator<Item = &'a Vpl>) -> VoxelSh {
    let mut out = VoxelSh::default();
    let (mut wsum, mut psum, mut count, mut mean) = (0.0f64, DVec3::ZERO, 0u64, DVec3::ZERO);
    for v in vpls {
        for (c, p) in out.coeffs.iter_mut().zip(project_vpl(v)) {
            *c += p;
        }
        let w = luminance(v.flux).max(0.0) as f64;
        wsum += w;
        psum += v.position.as_dvec3() * w;
        count += 1;
        mean += v.position.as_dvec3();
    }
    out.affine = affine(&out.coeffs);
    out.centroid = if wsum > 0.0 {
        (psum / wsum).as_vec3()
    } else if count > 0 {
        (mean / count as f64).as_vec3()
    } else {
        Vec3::ZERO
    };
    out
}

/// `Σ_k c_k Y_k(ω)` as `a + b · ω`: band 0 is the constant `Y_0`, band 1 linear, so `b`'s
/// component along axis `e` is `Σ_{k ≥ 1} c_k Y_k(e)` and `a = c_0 Y_0`.
fn affine(coeffs: &[DVec3; COEFFS]) -> [DVec3; 4] {
    let mut out = [DVec3::ZERO; 4];
    let mut y = [0.0f64; COEFFS];
    for (axis, e) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
        sh::eval(ORDER, e, &mut y);
        out[0] = coeffs[0] * y[0];
        for k in 1..COEFFS {
            out[1 + axis] += coeffs[k] * y[k];
        }
    }
    out
}

impl VoxelSh {
    /// The radiant intensity the voxel sends along unit `dir` (W/sr per channel), clamped
    /// at zero (bands 0-1 ring below it behind the VPLs).
    #[inline]
    pub fn intensity(&self, dir: Vec3) -> DVec3 {
        let [a, bx, by, bz] = self.affine;
        let d = dir.as_dvec3();
        (a + bx * d.x + by * d.y + bz * d.z).max(DVec3::ZERO)
    }

    /// [`Self::intensity`] from the basis itself (the reference the affine form is
    /// tested against).
    pub fn intensity_by_basis(&self, dir: Vec3) -> DVec3 {
        let mut y = [0.0f64; COEFFS];
        sh::eval(ORDER, dir.as_dvec3(), &mut y);
        let mut i = DVec3::ZERO;
        for (c, yk) in self.coeffs.iter().zip(y) {
            i += *c * yk;
        }
        i.max(DVec3::ZERO)
    }

    /// The flux the coefficients carry, `√(4π) c_00` per channel (W).
    pub fn flux(&self) -> DVec3 {
        self.coeffs[0] * (4.0 * std::f64::consts::PI).sqrt()
    }
}
