//! Visibility filtering (VF): one bounce of indirect light from point proxies hashed into a
//! voxel grid, after Chen, Yen, Chen, Chen & Chien, "Visibility Filtering for Producing
//! Indirect Illumination" (Eurographics 2014; `003_66bd22f64a85d1d6.txt`). The stages, each
//! callable alone:
//!
//! 1. [`proxies`] (§3.1): points on the triangles in proportion to area (Halton
//!    barycentrics, Russian roulette for triangles owed less than one), each a disc, lit by
//!    shadow rays and turned into a first-bounce surface VPL ([`crate::lights::vpl`]).
//! 2. [`grid`] (eq. 1): the discs counting-sorted by voxel key into per-voxel ranges, densely
//!    or in a hashed table of `T` slots whose entries keep their voxel coordinates.
//! 3. [`sh`] (eq. 2-3): each voxel's VPLs as bands `l = 0..1` of their clamped-cosine
//!    emission about the voxel's flux-weighted centroid.
//! 4. [`march`] (Fig. 2c-d): sparse cosine rays per low-resolution pixel walk the voxels
//!    by 3D DDA, test that voxel's discs and keep the voxel of the nearest hit.
//! 5. [`filter`] (eq. 4): each pixel's list becomes the union over a window of the
//!    neighbours on the same surface (depth and normal tests).
//! 6. [`gather`] (eq. 5-6): per indirect-resolution pixel, the four low-resolution lists
//!    weighted bilinearly and by geometry, near voxels by their VPLs, far ones by SH.
//! 7. [`upsample`]: joint bilateral upsampling to the camera's resolution.
//!
//! The render floor (`render::vf`) runs them and adds direct light. Every stage is a pure
//! function of its inputs and the seed: the same seed gives the same image bit for bit for
//! any thread count (fixed chunks, per-pixel random streams `(seed, pixel, ray)`).

use crate::error::{Error, Result};

pub mod filter;
pub mod gather;
pub mod grid;
pub mod march;
pub mod proxies;
pub mod proxy_grid;
pub mod sh;
pub mod upsample;

#[cfg(test)]
mod tests;

/// Most proxies a render may ask for.
pub const MAX_PROXIES: u32 = 1 << 24;
/// Most voxels along one axis.
pub const MAX_VOXELS_PER_AXIS: u32 = 4096;
/// Most marching rays per low-resolution pixel.
pub const MAX_RAYS_PER_PIXEL: u32 = 4096;
/// Largest side of the visibility filter's window (odd).
pub const MAX_FILTER: u32 = 63;

/// How the gather decides which VPLs a pixel sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Visibility {
    /// The paper's: the voxels of the pixel's (filtered, interpolated) lists.
    Marched,
    /// One shadow ray per VPL and pixel, every voxel lit by its VPLs: the exact sum of
    /// `method="vpl"` over the same VPLs, the first link of the exactness chain that
    /// measures each stage's bias.
    Traced,
}

/// Parameters of VF (units and ranges per field). `Python` takes the same names.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VfParams {
    /// Proxies wanted (the expected count; `1..=MAX_PROXIES`).
    pub proxies: u32,
    /// Voxels along x, y, z (`1..=MAX_VOXELS_PER_AXIS` each) over the scene's bounds.
    pub voxels: [u32; 3],
    /// `(width, height)` of the marching G-buffer: at most `indirect` on each axis;
    /// `None`: [`DEFAULT_MARCHING`], clipped to `indirect`.
    pub marching: Option<[u32; 2]>,
    /// `(width, height)` the light is gathered at: at most the camera's on each axis;
    /// `None`: [`DEFAULT_INDIRECT`], clipped to the camera.
    pub indirect: Option<[u32; 2]>,
    /// Cosine-distributed rays per marching pixel (stratified), `1..=MAX_RAYS_PER_PIXEL`.
    pub rays_per_pixel: u32,
    /// Side of the square window of eq. 4 (`2m + 1`), odd, `1..=MAX_FILTER`.
    pub filter: u32,
    /// δ_d of eq. 4 and the gather: neighbours pass when `|d_q - d_p| <= depth_tol · d_p`;
    /// in `[0, 1]`.
    pub depth_tol: f32,
    /// δ_n: neighbours pass when `n_p · n_q >= 1 - normal_tol`; in `[0, 1]`.
    pub normal_tol: f32,
    /// `R` of eq. 6 (world units, `>= 0`, may be infinite): voxels whose centroid is
    /// nearer give their VPLs, farther ones their SH; `None`: [`DEFAULT_SH_RANGE_SHARE`] of
    /// the scene's diagonal.
    pub sh_range: Option<f32>,
    /// Voxels whose centroid lies at least this far (world units, `>= 0`, may be
    /// infinite: never) but nearer than `sh_range` give a diffuse receiver their VPLs
    /// pooled by sub-cell and normal ([`gather::merge`]) instead of each VPL; `None`:
    /// [`DEFAULT_MERGE_VOXELS`] voxel diagonals.
    pub merge_range: Option<f32>,
    /// Slots `T` of the hashed voxel table; `None`: dense storage when the grid has at
    /// most [`grid::DENSE_MAX_VOXELS`] voxels, else hashed with as many slots as
    /// non-empty voxels.
    pub table_slots: Option<u32>,
    /// σ_θ of eq. 7 (`> 0`, may be infinite): a Phong receiver's specular term towards
    /// each VPL or voxel is weighted by `exp(-½ ((1 - cos^η θ) / σ_θ)²)`
    /// ([`gather::specular_weight`]); infinite (the default) leaves Phong's specular term
    /// whole, as `method="vpl"` shades it.
    pub specular_sigma: f32,
    pub visibility: Visibility,
}

/// The paper's marching size (Table 1, Cornell box).
pub const DEFAULT_MARCHING: [u32; 2] = [64, 64];
/// The paper's indirect resolution.
pub const DEFAULT_INDIRECT: [u32; 2] = [256, 256];

/// `merge_range` when not given, in voxel diagonals: pools of a quarter voxel are then
/// seen from at least four of their sizes.
pub const DEFAULT_MERGE_VOXELS: f32 = 1.0;

/// `sh_range` when not given, as a share of the scene's bounding-box diagonal. Bands 0-1
/// hold a clamped cosine as `(1/4 + cos θ / 2)`: a quarter of the peak at grazing angles,
/// where the lobe has none, so far voxels seen edge-on (a sunlit floor from the walls)
/// came out too bright. Measured at 128x96 against the one-bounce reference (`direct =
/// False`, 256 spp), relMSE at shares 0.35 / 0.7 / ∞: cornell 0.0094 / 0.0019 / 0.0018
/// (blue was 1.37x the reference's mean at 0.35), room (sunlit) 0.064 / 0.0014 / 0.0013,
/// garage (sun) 0.232 / 0.231 / 0.231, each within 20% of the 0.35 share's seconds
/// (pooled VPLs, `merge_range`, made near voxels cheap).
pub const DEFAULT_SH_RANGE_SHARE: f32 = 0.7;

impl VfParams {
    /// The paper's Cornell box setting (24k proxies, 6³ voxels, marching 64², indirect
    /// 256², each clipped to the image, 7x7 filter) with 16 rays per marching pixel.
    pub const DEFAULT: Self = Self {
        proxies: 24_000,
        voxels: [6, 6, 6],
        marching: None,
        indirect: None,
        rays_per_pixel: 16,
        filter: 7,
        depth_tol: 0.1,
        normal_tol: 0.1,
        sh_range: None,
        merge_range: None,
        table_slots: None,
        specular_sigma: f32::INFINITY,
        visibility: Visibility::Marched,
    };

    /// The indirect and marching sizes for a `camera`-sized image (`(width, height)`):
    /// the given ones, else the defaults clipped to the camera and to `indirect`.
    pub fn sizes(&self, camera: [u32; 2]) -> ([u32; 2], [u32; 2]) {
        let indirect = self
            .indirect
            .unwrap_or([0, 1].map(|a| DEFAULT_INDIRECT[a].min(camera[a])));
        let marching = self
            .marching
            .unwrap_or([0, 1].map(|a| DEFAULT_MARCHING[a].min(indirect[a])));
        (indirect, marching)
    }

    /// Fails with an error naming the first parameter out of range; `camera` is the
    /// final image's `(width, height)`.
    pub fn validate(&self, camera: [u32; 2]) -> Result<()> {
        crate::error::check_range("proxies", self.proxies, 1, MAX_PROXIES)?;
        for v in self.voxels {
            crate::error::check_range("voxels", v, 1, MAX_VOXELS_PER_AXIS)?;
        }
        let (indirect, marching) = self.sizes(camera);
        for (name, size) in [("marching", marching), ("indirect", indirect)] {
            if size.contains(&0) {
                return Err(Error::invalid(
                    name,
                    format!("must be a positive (width, height), got {size:?}"),
                ));
            }
        }
        if indirect[0] > camera[0] || indirect[1] > camera[1] {
            return Err(Error::invalid(
                "indirect",
                format!("must not exceed the camera's {camera:?} on either axis, got {indirect:?}"),
            ));
        }
        if marching[0] > indirect[0] || marching[1] > indirect[1] {
            return Err(Error::invalid(
                "marching",
                format!("must not exceed indirect {indirect:?} on either axis, got {marching:?}"),
            ));
        }
        crate::error::check_range("rays_per_pixel", self.rays_per_pixel, 1, MAX_RAYS_PER_PIXEL)?;
        if self.filter.is_multiple_of(2) || self.filter > MAX_FILTER {
            return Err(Error::invalid(
                "filter",
                format!(
                    "must be an odd window side in [1, {MAX_FILTER}], got {}",
                    self.filter
                ),
            ));
        }
        for (name, t) in [
            ("depth_tol", self.depth_tol),
            ("normal_tol", self.normal_tol),
        ] {
            if !(0.0..=1.0).contains(&t) {
                return Err(Error::invalid(name, format!("must lie in [0, 1], got {t}")));
            }
        }
        if let Some(r) = self.sh_range {
            if r.is_nan() || r < 0.0 {
                return Err(Error::invalid(
                    "sh_range",
                    format!("must be >= 0 (world units; inf: VPLs only), got {r}"),
                ));
            }
        }
        if self.specular_sigma.is_nan() || self.specular_sigma <= 0.0 {
            return Err(Error::invalid(
                "specular_sigma",
                format!(
                    "must be > 0 (inf: Phong's specular term unweighted), got {}",
                    self.specular_sigma
                ),
            ));
        }
        if let Some(r) = self.merge_range {
            if r.is_nan() || r < 0.0 {
                return Err(Error::invalid(
                    "merge_range",
                    format!("must be >= 0 (world units; inf: never pool), got {r}"),
                ));
            }
        }
        if self.table_slots == Some(0) {
            return Err(Error::invalid("table_slots", "must be at least 1, got 0"));
        }
        Ok(())
    }
}

impl Default for VfParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Row-major low-resolution pixel neighbourhoods need the pixel's surface: what the
/// filter, the gather and the upsampler compare (eq. 4's δ_d and δ_n, eq. 5's `w_G`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surfel {
    /// Distance from the eye (world units); infinite for a miss.
    pub depth: f32,
    /// Unit normal facing the camera; zero for a miss.
    pub normal: glam::Vec3,
}

impl Surfel {
    /// A pixel that saw no surface.
    pub const MISS: Self = Self {
        depth: f32::INFINITY,
        normal: glam::Vec3::ZERO,
    };

    /// Whether `other` lies on the same continuous surface (δ_d · δ_n = 1 of eq. 4).
    #[inline]
    pub fn same_surface(&self, other: &Surfel, depth_tol: f32, normal_tol: f32) -> bool {
        self.depth.is_finite()
            && other.depth.is_finite()
            && (other.depth - self.depth).abs() <= depth_tol * self.depth
            // A unit normal's square may round below 1: a pixel always passes against itself.
            && self.normal.dot(other.normal) >= 1.0 - normal_tol - 1e-6
    }

    /// The Gaussian joint-bilateral weight `w_G` of eq. 5 between this pixel and `other`:
    /// `exp(-½ (Δd / (σ_d d))² - ½ ((1 - n·n') / σ_n)²)` with `σ = tol` (a tolerance of 0
    /// keeps only exact matches); zero when either missed.
    #[inline]
    pub fn weight(&self, other: &Surfel, depth_tol: f32, normal_tol: f32) -> f32 {
        if !(self.depth.is_finite() && other.depth.is_finite()) {
            return 0.0;
        }
        let dd = (other.depth - self.depth).abs() / self.depth.max(f32::MIN_POSITIVE);
        let dn = (1.0 - self.normal.dot(other.normal)).max(0.0);
        let term = |x: f32, s: f32| {
            if s > 0.0 {
                (x / s).powi(2)
            } else if x > 0.0 {
                f32::INFINITY
            } else {
                0.0
            }
        };
        (-0.5 * (term(dd, depth_tol) + term(dn, normal_tol))).exp()
    }
}

/// The surfels of a G-buffer, row-major.
pub fn surfels(g: &crate::camera::GBuffer) -> Vec<Surfel> {
    (0..g.len())
        .map(|i| {
            if g.object[i] < 0 {
                Surfel::MISS
            } else {
                Surfel {
                    depth: g.depth[i],
                    normal: glam::Vec3::from(g.normal[i]),
                }
            }
        })
        .collect()
}
