//! Virtual point lights (VPLs): the light set of instant radiosity (Keller 1997; survey
//! `004_d2289ee9e28a0f98.txt` §6.2.1), with the parameters and statistics of its light
//! tracing. The light paths that deposit them are traced by
//! `estimators::many_lights::light_paths` ([`VplSet::trace`]), which connects them to
//! receivers too; this module holds the set itself.

use glam::{DVec3, Vec3};

use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::lights::AreaLight;
use crate::math::{triangle_cross, LUMINANCE_F32};

/// Largest number of VPLs a set may hold.
pub const MAX_VPLS: u64 = 1 << 26;

/// Most generations of surface VPLs per path.
pub const MAX_DEPTH: u32 = 64;

/// What a VPL is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum VplKind {
    /// A point on an area light (or given by the user): an oriented point light of
    /// intensity `Φ cos θ / π` about `normal`, zero behind.
    Emitter,
    /// A direction of the environment map: light from `normal` (unit, towards the map) of
    /// irradiance `Φ / disk_area` on a surface facing it.
    Env,
    /// A light-path hit: reflects its incident flux `Φ` (arriving from `incident`) by
    /// `material`.
    Surface,
    /// A whole area light of the scene (`light - 1` indexes `Scene::area_lights`) of power
    /// `Φ = π A L̄`. Its term without visibility at a receiver (what distributions read) is
    /// the quadrature over `points` fixed stratified points on it ([`area_points`]); a
    /// gather that picks it samples a fresh point by area for its shadow ray, so the
    /// estimate stays unbiased for the true area light.
    Area {
        /// `K >= 1`, the fixed points of the quadrature.
        points: u32,
    },
}

impl VplKind {
    /// True for [`VplKind::Area`].
    #[inline(always)]
    pub fn is_area(self) -> bool {
        matches!(self, VplKind::Area { .. })
    }
}

/// One virtual point light.
///
/// Invariants: `flux` finite and `>= 0` per channel; `normal` unit; `incident` unit for
/// [`VplKind::Surface`] (zero otherwise); `origin` is `position` moved off the surface
/// along `normal` by the scene's epsilon (the start of its shadow rays). For
/// [`VplKind::Area`], `position` is the light's area-weighted centroid and `normal` its
/// area-weighted mean normal (for display and bounds); its shadow rays start at sampled
/// points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vpl {
    /// Position (world units); meaningless for [`VplKind::Env`] (zero).
    pub position: Vec3,
    /// Shadow-ray origin: `position` offset along `normal`.
    pub origin: Vec3,
    /// Unit normal on the side the light leaves from; for [`VplKind::Env`], the unit
    /// direction towards the light.
    pub normal: Vec3,
    /// Unit direction the photon arrived from (towards the previous vertex; surface VPLs).
    pub incident: Vec3,
    /// The surface's material (surface VPLs; white Lambert for emitters).
    pub material: Material,
    /// Flux, W per channel (or the map's radiance units times m²).
    pub flux: Vec3,
    pub kind: VplKind,
    /// Generation: 0 for light VPLs, `j >= 1` for the `j`-th hit of a path.
    pub bounce: u32,
    /// The light its path started at: 0 the map, `k >= 1` area light `k - 1`
    /// ([`u32::MAX`] for user-given lights: `VplSet::from_lights`,
    /// `VplSet::from_directions`). For [`VplKind::Area`], the area light it is (`k >= 1`).
    pub light: u32,
}

impl Vpl {
    /// `Φ f_v` of a point VPL whose `f_v` does not depend on directions (a Lambert surface
    /// or an emitter), W/sr per channel: its term is then `f_x Φ f_v G`.
    pub fn diffuse_intensity(&self) -> Option<Vec3> {
        match (self.kind, self.material) {
            (VplKind::Env | VplKind::Area { .. }, _) => None,
            (VplKind::Surface, Material::Lambert { albedo }) => {
                Some(self.flux * Vec3::from(albedo) * std::f32::consts::FRAC_1_PI)
            }
            (VplKind::Surface, _) => None,
            (VplKind::Emitter, _) => Some(self.flux * std::f32::consts::FRAC_1_PI),
        }
    }
}

/// Importance-driven acceptance (survey §6.2.2, Algorithm 11).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Importance {
    /// `ε` of `p_i = min(Φ_i / Φ_v + ε, 1)`, in `(0, 1]`.
    pub epsilon: f32,
    /// Pilot paths that estimate `Φ_v` (and the VPLs per path), `>= 1`.
    pub pilot_paths: u32,
    /// Side of the (square-pixel) image of camera points `Φ_i` averages over: `width`
    /// points across, as many rows as the camera's aspect gives.
    pub view_width: u32,
}

impl Importance {
    /// `ε = 0.05`, 4000 pilot paths, a 16-point-wide view.
    pub const DEFAULT: Self = Self {
        epsilon: 0.05,
        pilot_paths: 4000,
        view_width: 16,
    };
}

/// Parameters of [`VplSet::trace`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceParams {
    /// VPLs wanted, `1..=MAX_VPLS` (the set has about as many; module docs).
    pub count: u64,
    /// Generations of surface VPLs per path, `1..=MAX_DEPTH`.
    pub depth: u32,
    pub seed: u64,
    /// Acceptance by importance to the camera's view, or every VPL.
    pub importance: Option<Importance>,
    /// Whether the set keeps the light VPLs (direct light); without, `count` counts
    /// surface VPLs, all of them for the indirect light.
    pub lights: bool,
}

impl TraceParams {
    /// `count` VPLs of one bounce, seed 0, with importance-driven acceptance.
    pub const fn new(count: u64) -> Self {
        Self {
            count,
            depth: 1,
            seed: 0,
            importance: Some(Importance::DEFAULT),
            lights: true,
        }
    }

    /// Fails with an error naming the first parameter out of range.
    pub fn validate(&self) -> Result<()> {
        crate::error::check_range("count", self.count, 1, MAX_VPLS)?;
        crate::error::check_range("depth", self.depth, 1, MAX_DEPTH)?;
        if let Some(imp) = self.importance {
            if !(imp.epsilon > 0.0 && imp.epsilon <= 1.0) {
                return Err(Error::invalid(
                    "epsilon",
                    format!("must lie in (0, 1], got {}", imp.epsilon),
                ));
            }
            if imp.pilot_paths == 0 {
                return Err(Error::invalid("pilot_paths", "must be at least 1, got 0"));
            }
            if !(1..=1024).contains(&imp.view_width) {
                return Err(Error::invalid(
                    "view_width",
                    format!("must lie in [1, 1024], got {}", imp.view_width),
                ));
            }
        }
        Ok(())
    }
}

/// Figures of one trace.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TraceStats {
    /// Light paths traced for the set (`P`).
    pub paths: u64,
    /// Pilot paths traced.
    pub pilot_paths: u64,
    /// Closest-hit rays of the light paths (pilot included).
    pub path_rays: u64,
    /// Shadow rays of the importance estimates (pilot included).
    pub shadow_rays: u64,
    /// Surface VPLs rejected by the acceptance test.
    pub rejected: u64,
    /// `Φ_v`, the pilot's mean contribution of a surface VPL (luminance), 0 without
    /// importance.
    pub mean_contribution: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// A set of VPLs and what their fluxes are normalised by.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VplSet {
    pub vpls: Vec<Vpl>,
    /// `π R²` of the map's disk (m²): a map VPL's irradiance is `Φ / disk_area`.
    pub disk_area: f32,
    /// Fingerprint of the geometry the set was traced in.
    pub fingerprint: u64,
    pub stats: TraceStats,
}

/// Row `i` of user-given VPL arrays, checked: a finite `position`, a finite non-zero
/// `normal` (returned unit) and `values` (the row of the array named `values_name`: flux or
/// irradiance) finite and `>= 0`. Fails naming the array and the row.
pub fn checked_row(
    i: usize,
    position: [f32; 3],
    normal: [f32; 3],
    values: [f32; 3],
    values_name: &str,
) -> Result<(Vec3, Vec3)> {
    let p = Vec3::from(position);
    if !p.is_finite() {
        return Err(Error::invalid(
            "positions",
            format!("row {i} is not finite: {position:?}"),
        ));
    }
    let n = Vec3::from(normal);
    let len = n.length();
    if !(len.is_finite() && len > 0.0) {
        return Err(Error::invalid(
            "normals",
            format!("row {i} must be finite and non-zero, got {normal:?}"),
        ));
    }
    if !values.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return Err(Error::invalid(
            values_name,
            format!("row {i} must be finite and >= 0, got {values:?}"),
        ));
    }
    Ok((p, n / len))
}

/// Rec. 709 luminance.
#[inline]
pub fn luminance(v: Vec3) -> f32 {
    v.dot(Vec3::from_array(LUMINANCE_F32))
}

impl VplSet {
    /// Number of VPLs.
    pub fn len(&self) -> usize {
        self.vpls.len()
    }

    /// True for a set without VPLs.
    pub fn is_empty(&self) -> bool {
        self.vpls.is_empty()
    }

    /// Sum of the fluxes of the VPLs of generation `bounce`, per channel (f64).
    pub fn total_flux(&self, bounce: u32) -> DVec3 {
        self.vpls
            .iter()
            .filter(|v| v.bounce == bounce)
            .map(|v| v.flux.as_dvec3())
            .sum()
    }
}

/// Most fixed points per area light ([`VplKind::Area`]).
pub const MAX_AREA_POINTS: u32 = 1 << 16;

/// One of an area light's fixed quadrature points ([`area_points`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AreaPoint {
    /// The point on the light (world units).
    pub position: Vec3,
    /// Its triangle's unit normal (the side it emits to).
    pub normal: Vec3,
    /// Radiance leaving it (W/(m² sr) per channel) times its share of the area, `A / K`
    /// (m²): its term at a receiver is `f_x · value · cos θ_x cos θ_y / d²`.
    pub value: Vec3,
}

/// Van der Corput's radical inverse of `i` in base 2, in `[0, 1)`.
#[inline]
fn radical_inverse2(i: u32) -> f32 {
    (i.reverse_bits() as f64 / 4_294_967_296.0) as f32
}

/// Calls `f` with the `k` fixed stratified points of `light`: the Hammersley set
/// `((i + ½)/k, φ₂(i))` of the unit square, its first coordinate walked along the
/// triangles' cumulative area (so each triangle gets points in proportion to its area)
/// and both mapped onto the triangle by the square-root warp (uniform by area, as
/// `AreaLight::sample`). Degenerate triangles get none. `O(T + k)` for `T` triangles.
pub fn area_points(light: &AreaLight, k: u32, mut f: impl FnMut(AreaPoint)) {
    let k = k.max(1);
    let total = light.area();
    let share = (total / k as f64) as f32;
    let area_of = |tri: &[Vec3; 3]| 0.5 * triangle_cross(tri).as_dvec3().length();
    // The last triangle with area takes what rounding leaves past the running sum.
    let last = light
        .triangles()
        .iter()
        .rposition(|tri| area_of(tri) > 0.0)
        .unwrap_or(0);
    let mut before = 0.0f64;
    let mut i = 0u32;
    for (t, tri) in light.triangles().iter().enumerate() {
        let area = area_of(tri);
        let after = before + area;
        if area > 0.0 {
            let n = light.normal(t);
            // Points whose first coordinate falls in this triangle's share of the area.
            while i < k {
                let u0 = (i as f64 + 0.5) / k as f64 * total;
                if u0 >= after && t < last {
                    break;
                }
                let local = ((u0 - before) / area).clamp(0.0, 1.0 - f64::EPSILON) as f32;
                let su = local.sqrt();
                let (b0, b1) = (1.0 - su, radical_inverse2(i) * su);
                let [a, b, c] = *tri;
                let y = a * b0 + b * b1 + c * (1.0 - b0 - b1);
                f(AreaPoint {
                    position: y,
                    normal: n,
                    value: light.radiance_at(y) * share,
                });
                i += 1;
            }
        }
        before = after;
    }
}

impl TraceStats {
    /// The figures of two traces together: counts and seconds add, `mean_contribution` is
    /// the mean of the two weighted by their pilot paths (0 when neither had a pilot).
    pub fn combined(&self, o: &TraceStats) -> TraceStats {
        let pilots = self.pilot_paths + o.pilot_paths;
        let mean_contribution = if pilots > 0 {
            (self.mean_contribution * self.pilot_paths as f64
                + o.mean_contribution * o.pilot_paths as f64)
                / pilots as f64
        } else {
            0.0
        };
        TraceStats {
            paths: self.paths + o.paths,
            pilot_paths: pilots,
            path_rays: self.path_rays + o.path_rays,
            shadow_rays: self.shadow_rays + o.shadow_rays,
            rejected: self.rejected + o.rejected,
            mean_contribution,
            seconds: self.seconds + o.seconds,
        }
    }
}

impl VplSet {
    /// True when the set holds a [`VplKind::Env`] light (whose flux `disk_area` scales).
    pub fn has_directions(&self) -> bool {
        self.vpls.iter().any(|v| v.kind == VplKind::Env)
    }

    /// The union of two sets of the same geometry: `self`'s VPLs, then `other`'s. Both
    /// sets' lights add up (two estimates of the same light counted twice are twice the
    /// light: that is the caller's choice). Directional lights keep their irradiance
    /// `Φ / disk_area`: `other`'s are rescaled to `self`'s disk (or the other way when
    /// only `other` has any). Stats combine by [`TraceStats::combined`]. Fails naming
    /// `other` when the fingerprints differ or the union would exceed [`MAX_VPLS`].
    pub fn concat(&self, other: &VplSet) -> Result<VplSet> {
        if self.fingerprint != other.fingerprint {
            return Err(Error::invalid(
                "other",
                format!(
                    "VPLs of another scene (fingerprint {:#018x}, this set's {:#018x})",
                    other.fingerprint, self.fingerprint
                ),
            ));
        }
        let n = self.len() as u64 + other.len() as u64;
        if n > MAX_VPLS {
            return Err(Error::invalid(
                "other",
                format!("the union would hold {n} VPLs, more than {MAX_VPLS}"),
            ));
        }
        crate::error::check_memory(
            (n as usize).saturating_mul(std::mem::size_of::<Vpl>()),
            "vpls",
        )?;
        // The disk the union's directional fluxes are normalised by.
        let disk_area = if self.has_directions() || !other.has_directions() {
            self.disk_area
        } else {
            other.disk_area
        };
        let rescale = |set: &VplSet, v: &Vpl| {
            let mut v = *v;
            if v.kind == VplKind::Env && set.disk_area != disk_area && set.disk_area > 0.0 {
                v.flux *= disk_area / set.disk_area;
            }
            v
        };
        let mut vpls = Vec::with_capacity(n as usize);
        vpls.extend(self.vpls.iter().map(|v| rescale(self, v)));
        vpls.extend(other.vpls.iter().map(|v| rescale(other, v)));
        Ok(VplSet {
            vpls,
            disk_area,
            fingerprint: self.fingerprint,
            stats: self.stats.combined(&other.stats),
        })
    }
}

impl std::ops::Add for &VplSet {
    type Output = Result<VplSet>;

    /// [`VplSet::concat`].
    fn add(self, other: &VplSet) -> Result<VplSet> {
        self.concat(other)
    }
}
