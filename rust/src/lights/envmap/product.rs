//! The product distribution of one shading point (CAM08 §5.5; Clarberg & Akenine-Möller,
//! "Practical Product Importance Sampling", 2008): a coarse product `L_c · B~_c` over the
//! cells of one octahedral level picks a cell; the environment map's own quadtree picks a
//! texel inside it, so `p(ω) = L(ω) · B~(ω) / L_ns` with `L_ns = Σ_c L_c · B~_c` (CAM08
//! eq. 3), where `L` is the map's sampling weight (luminance). `B~` is conservative
//! ([`Material::product_cells`]), so `p > 0` wherever the integrand is. Also the product
//! guided by a visibility estimate per cell ([`GuidedProduct`]).

use glam::{DVec2, UVec2, Vec3};

use super::EnvMap;
use crate::bsdf::Material;
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::{morton_encode, square_to_sphere, texel_of, texel_solid_angle};

/// The product distribution of one shading point (CAM08 §5.5).
///
/// Invariants: `cells` holds `L_c · B~_c` over the `4^level` cells in Morton order, with a
/// positive total `L_ns`; `level` does not exceed the environment's quadtree depth.
#[derive(Clone, Debug)]
pub struct ProductDistribution {
    level: u32,
    bsdf_cells: Vec<f32>,
    cells: QuadPyramid,
}

impl ProductDistribution {
    /// Builds the product of `env`'s cell sums at `level` (capped at the map's depth) and
    /// `B~` of `material` at `(normal, wo)`. `None` when the product is zero everywhere
    /// (black map, or a surface that reflects nothing towards `wo`).
    pub fn new(
        env: &EnvMap,
        material: &Material,
        normal: Vec3,
        wo: Vec3,
        level: u32,
    ) -> Option<Self> {
        let dist = env.distribution()?;
        let level = level.min(dist.depth());
        let mut bsdf_cells = vec![0.0f32; 1 << (2 * level)];
        material.product_cells(normal, wo, level, &mut bsdf_cells);
        Self::with_cells(env, level, bsdf_cells)
    }

    /// The product of this one's cells (`B~`) capped by those of `lobe` at the same
    /// `(normal, wo)`: `L · min(B~_lobe, B~)` per cell, zero wherever this product is. The
    /// control variate's part for one lobe of a material (`Material::diffuse_lobe`).
    pub fn lobe_part(&self, env: &EnvMap, lobe: &Material, normal: Vec3, wo: Vec3) -> Option<Self> {
        let mut cells = vec![0.0f32; self.bsdf_cells.len()];
        lobe.product_cells(normal, wo, self.level, &mut cells);
        for (c, &b) in cells.iter_mut().zip(&self.bsdf_cells) {
            *c = c.min(b);
        }
        Self::with_cells(env, self.level, cells)
    }

    /// The product of `env`'s cell sums at `level` (at most the map's depth) and
    /// `bsdf_cells` (Morton order, `4^level` of them).
    fn with_cells(env: &EnvMap, level: u32, bsdf_cells: Vec<f32>) -> Option<Self> {
        let dist = env.distribution()?;
        let product: Vec<f64> = dist
            .level(level)
            .iter()
            .zip(&bsdf_cells)
            .map(|(&l, &b)| l * b as f64)
            .collect();
        let cells = QuadPyramid::from_morton_unchecked(product);
        (cells.total() > 0.0).then_some(Self {
            level,
            bsdf_cells,
            cells,
        })
    }

    /// `L_ns = Σ_c L_c · B~_c` (CAM08 eq. 3), in the units of the map's sampling weights.
    pub fn normalization(&self) -> f64 {
        self.cells.total()
    }

    /// Samples a direction from `u ∈ [0,1)^2`: a cell of the product, then a texel of the
    /// map inside it. Returns the direction, its texel and its solid-angle pdf.
    pub fn sample(&self, env: &EnvMap, u: DVec2) -> (Vec3, UVec2, f64) {
        let s = self.sample_point(env, u);
        (s.direction, s.texel, s.pdf)
    }

    /// [`Self::sample`] with everything the control variate needs: the point of the
    /// equal-area square the direction comes from and `B~` of its cell.
    pub fn sample_point(&self, env: &EnvMap, u: DVec2) -> ProductSample {
        let (cell, rest) = self
            .cells
            .sample(u)
            .expect("the product has a positive total");
        self.sample_in_cell(env, morton_encode(cell.x, cell.y), rest)
    }

    /// The draw of [`Self::sample_point`] once its cell (Morton code) is chosen: a texel of
    /// the map inside it by the map's own quadtree, from the cell's rescaled `rest`.
    fn sample_in_cell(&self, env: &EnvMap, cell_code: u32, rest: DVec2) -> ProductSample {
        let dist = env
            .distribution()
            .expect("a product exists only for a lit map");
        let (texel, within) = dist.descend(self.level, cell_code, rest);
        let res = env.resolution();
        let square = (texel.as_dvec2() + within) / res as f64;
        let bsdf = self.bsdf_cells[cell_code as usize] as f64;
        let pdf = bsdf * dist.weight(texel) / self.normalization() / texel_solid_angle(res);
        ProductSample {
            // The estimators read every density and the radiance at `texel`, so a direction
            // that rounding maps a hair across the texel's border changes nothing.
            direction: square_to_sphere(square.as_vec2()),
            texel,
            square,
            bsdf,
            pdf,
        }
    }

    /// Octahedral level of the cells (`4^level` of them).
    pub fn level(&self) -> u32 {
        self.level
    }

    /// `B~` of every cell, Morton order.
    pub fn bsdf_cells(&self) -> &[f32] {
        &self.bsdf_cells
    }

    /// The product `L_c B~_c` as a quadtree of sums (levels `0..=level`, Morton order), in
    /// the map's sampling weights (luminance per texel, summed).
    pub fn pyramid(&self) -> &QuadPyramid {
        &self.cells
    }

    /// The product cell (Morton code) holding `texel` of the map.
    #[inline]
    pub fn cell_of(&self, env: &EnvMap, texel: UVec2) -> usize {
        let shift = env.resolution().trailing_zeros() - self.level;
        morton_encode(texel.x >> shift, texel.y >> shift) as usize
    }

    /// Product sampling guided by a visibility estimate: cells drawn in proportion to
    /// `L_c B~_c v_c` for `visibility[c] = v_c ∈ [0, 1]` (Morton order, one per cell), texels
    /// inside a cell as by the product. `None` when that is zero everywhere.
    pub fn guided(&self, visibility: Vec<f32>) -> Option<GuidedProduct> {
        debug_assert_eq!(visibility.len(), self.bsdf_cells.len());
        let weights: Vec<f64> = self
            .cells
            .level(self.level)
            .iter()
            .zip(&visibility)
            .map(|(&w, &v)| w * v as f64)
            .collect();
        let cells = QuadPyramid::from_morton_unchecked(weights);
        let total = cells.total();
        (total > 0.0).then(|| GuidedProduct {
            visibility,
            scale: self.normalization() / total,
            cells,
        })
    }

    /// Solid-angle pdf of sampling a direction in `texel` of the map.
    pub fn texel_pdf(&self, env: &EnvMap, texel: UVec2) -> f64 {
        let dist = env
            .distribution()
            .expect("a product exists only for a lit map");
        self.texel_pdf_in(env, dist, texel, self.normalization())
    }

    /// The pdf of `texel` of `env` (whose distribution is `dist`) for these cells and
    /// `normalization`.
    fn texel_pdf_in(
        &self,
        env: &EnvMap,
        dist: &QuadPyramid,
        texel: UVec2,
        normalization: f64,
    ) -> f64 {
        let b = self.bsdf_cells[self.cell_of(env, texel)] as f64;
        b * dist.weight(texel) / normalization / texel_solid_angle(env.resolution())
    }

    /// Solid-angle pdf of [`Self::sample`] producing `dir`.
    pub fn pdf(&self, env: &EnvMap, dir: Vec3) -> f64 {
        self.texel_pdf(env, texel_of(dir, env.resolution()))
    }

    /// The pdf at `dir` of the product of these cells (`B~`) with another map `other` of
    /// the same resolution, whose product's normalization `Σ_c L_c B~_c` is
    /// `normalization`, without building it: the relighter's density of samples drawn
    /// under an earlier map, same material.
    pub fn pdf_with_map(&self, other: &EnvMap, normalization: f64, dir: Vec3) -> f64 {
        let Some(dist) = other.distribution() else {
            return 0.0;
        };
        debug_assert!(other.resolution().trailing_zeros() >= self.level);
        self.texel_pdf_in(
            other,
            dist,
            texel_of(dir, other.resolution()),
            normalization,
        )
    }
}

/// Product sampling guided by a visibility estimate per cell ([`ProductDistribution::guided`]):
/// `p_guided(ω) = p_product(ω) · v_c · L_ns / W`, `W = Σ_c L_c B~_c v_c`. The renderer's
/// control variate takes `v_c` from the cache's records (the share of the cell that the
/// interpolated records see), so a point in shadow spends its samples where its records see
/// the sky instead of where the bright but occluded part of the product lies. Like any
/// technique of the mixture it needs no exact `v`: the other techniques cover the cells it
/// calls occluded.
#[derive(Clone, Debug)]
pub struct GuidedProduct {
    visibility: Vec<f32>,
    /// `L_ns / W`.
    scale: f64,
    cells: QuadPyramid,
}

impl GuidedProduct {
    /// Draws a direction from `u ∈ [0,1)²`: a cell by `L_c B~_c v_c`, then a texel of the
    /// map inside it. The sample's `pdf` is the guided one.
    pub fn sample_point(
        &self,
        product: &ProductDistribution,
        env: &EnvMap,
        u: DVec2,
    ) -> ProductSample {
        let (cell, rest) = self.cells.sample(u).expect("a positive total");
        let code = morton_encode(cell.x, cell.y);
        let mut s = product.sample_in_cell(env, code, rest);
        s.pdf *= self.ratio(code as usize);
        s
    }

    /// `p_guided / p_product` in product cell `cell` (Morton code).
    #[inline]
    pub fn ratio(&self, cell: usize) -> f64 {
        self.visibility[cell] as f64 * self.scale
    }
}

/// One draw of [`ProductDistribution::sample_point`].
#[derive(Clone, Copy, Debug)]
pub struct ProductSample {
    /// Unit direction.
    pub direction: Vec3,
    /// The map's texel that contains it.
    pub texel: UVec2,
    /// Its point of the equal-area square, `[0,1)²` (what the direction was mapped from).
    pub square: DVec2,
    /// `B~` of the product cell that contains it.
    pub bsdf: f64,
    /// Solid-angle pdf, sr⁻¹ (`> 0`).
    pub pdf: f64,
}
