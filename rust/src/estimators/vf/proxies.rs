//! VF §3.1: point proxies. `count` points spread over the scene's triangles in proportion
//! to area, each a disc (for marching, [`super::march`]) and, once lit, a first-bounce
//! surface VPL (for the gather, [`super::gather`]).
//!
//! - Triangle `t` of area `A_t` is owed `n_t = count · A_t / A` proxies (`A` the total
//!   area). It gets `floor(n_t)`, plus one more when a hash of its vertices' positions
//!   (and the seed) falls below `n_t - floor(n_t)`: the paper's Russian roulette, so a
//!   triangle 1e-6 of the mean area still gets its share in expectation and no triangle's
//!   proxies depend on the others'.
//! - Barycentrics are Halton points (bases 2 and 3) folded into the triangle, the sequence
//!   running on across triangles in triangle order.
//! - Every proxy stands for the same area `a = A / count` (so a flux `E · a` is unbiased
//!   for the light a triangle reflects), and its disc has the radius of that area,
//!   `r = DISC_SCALE · √(a / π)`: the density is uniform by construction, so the local
//!   density is the global one.
//! - Light (§3.1, "the scene depth is rasterized from the light"): here shadow rays. Each
//!   side of a proxy gets [`LIGHT_SAMPLES`] MIS estimates of its direct irradiance `E`
//!   (a white Lambert's reflected radiance times π); a lit side becomes a
//!   [`VplKind::Surface`] VPL of flux `E · a`, bounce 1, facing that side
//!   ([`surface_vpls`]).
//!
//! Deterministic: placement is sequential over triangles, lighting reads the stream
//! `(seed, proxy, side)` and runs in the scene's fixed ray chunks.

use glam::Vec3;

use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::estimators::direct::{DirectCounters, Lighting, Method, ShadingPoint};
use crate::geometry::Scene;
use crate::lights::vpl::{checked_row, TraceStats, Vpl, VplKind, VplSet};
use crate::math::triangle_cross;
use crate::sampling::rng::{mix64, SampleRng};

/// Disc radius over the radius of a proxy's share of the area: overlapping discs close
/// most of the gaps that Halton points on neighbouring triangles leave.
pub const DISC_SCALE: f32 = 1.25;

/// Direct-light estimates per side of a proxy.
pub const LIGHT_SAMPLES: u32 = 4;

/// The proxies of a scene: structure of arrays, in placement order (triangle by triangle).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Proxies {
    /// Points on the triangles (world units).
    pub position: Vec<Vec3>,
    /// Unit geometric normals of their triangles (as wound).
    pub normal: Vec<Vec3>,
    /// Triangle of each proxy.
    pub prim: Vec<u32>,
    /// Object of each proxy.
    pub object: Vec<u32>,
    /// Area each proxy stands for, `A / count` (world units²).
    pub area: f32,
    /// Radius of every disc (world units).
    pub radius: f32,
}

impl Proxies {
    /// Number of proxies.
    pub fn len(&self) -> usize {
        self.position.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }
}

/// Radical inverse of `i` in base `b` (Halton's coordinate).
fn radical_inverse(mut i: u64, b: u64) -> f32 {
    let (mut inv, mut f) = (0.0f64, 1.0f64 / b as f64);
    while i > 0 {
        inv += (i % b) as f64 * f;
        i /= b;
        f /= b as f64;
    }
    inv as f32
}

/// A uniform number in `[0, 1)` from the positions of a triangle's vertices and the seed:
/// the roulette's draw, independent of the triangle's index.
fn position_hash(tri: &[Vec3; 3], seed: u64) -> f64 {
    let mut h = mix64(seed ^ 0x5646_5052_4f58_5953);
    for v in tri {
        for c in v.to_array() {
            h = mix64(h ^ c.to_bits() as u64);
        }
    }
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Places about `count` proxies on `scene`'s triangles (module docs). Fails naming
/// `proxies` when `count` is 0 and `scene` when it has no area.
pub fn place(scene: &Scene, count: u32, seed: u64) -> Result<Proxies> {
    if count == 0 {
        return Err(Error::invalid("proxies", "must be at least 1, got 0"));
    }
    let mesh = scene.mesh();
    let areas: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| 0.5 * triangle_cross(t).as_dvec3().length())
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(Error::invalid(
            "scene",
            "has no triangle of positive, finite area to place proxies on",
        ));
    }
    crate::error::check_memory(
        (count as usize).saturating_mul(2 * std::mem::size_of::<Vec3>() + 16),
        "proxies",
    )?;
    let per_area = count as f64 / total;
    let mut out = Proxies {
        area: (total / count as f64) as f32,
        ..Proxies::default()
    };
    out.radius = DISC_SCALE * (out.area / std::f32::consts::PI).sqrt();
    let mut halton = 1u64;
    for (t, (tri, &a)) in mesh.triangles.iter().zip(&areas).enumerate() {
        if a.is_nan() || a <= 0.0 {
            continue;
        }
        let owed = a * per_area;
        let whole = owed.floor();
        let k = whole as u64 + (position_hash(tri, seed) < owed - whole) as u64;
        if k == 0 {
            continue;
        }
        let n = triangle_cross(tri).normalize();
        let object = mesh.object_ids[t];
        for _ in 0..k {
            let (mut u, mut v) = (radical_inverse(halton, 2), radical_inverse(halton, 3));
            halton += 1;
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            out.position
                .push(tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v);
            out.normal.push(n);
            out.prim.push(t as u32);
            out.object.push(object);
        }
    }
    Ok(out)
}

/// The direct irradiance on each side of every proxy (W/m² per channel; side 0 along the
/// proxy's normal, side 1 against it), [`LIGHT_SAMPLES`] MIS estimates each.
pub fn irradiance(
    lighting: &Lighting,
    proxies: &Proxies,
    seed: u64,
    threads: Option<usize>,
) -> Result<Vec<[Vec3; 2]>> {
    let scene = lighting.scene;
    // A white Lambert reflects E / π towards any viewer: its radiance times π is E.
    let white = Material::Lambert { albedo: [1.0; 3] };
    scene.map_rays(proxies.len(), threads, |i, bvh| {
        let mut out = [Vec3::ZERO; 2];
        let mut counters = DirectCounters::default();
        for (side, e) in out.iter_mut().enumerate() {
            let n = if side == 0 {
                proxies.normal[i]
            } else {
                -proxies.normal[i]
            };
            let sp = ShadingPoint {
                origin: scene.offset_point(proxies.position[i], n),
                normal: n,
                wo: n,
                material: white,
            };
            let mut sum = Vec3::ZERO;
            for s in 0..LIGHT_SAMPLES {
                let rng = SampleRng::new(
                    mix64(seed ^ 0x5646_4c49_4748_5400),
                    i as u64,
                    (side as u64) << 32 | s as u64,
                );
                sum += lighting.estimate(&sp, Method::Mis, &rng, &mut counters, bvh);
            }
            *e = sum * (std::f32::consts::PI / LIGHT_SAMPLES as f32);
        }
        out
    })
}

/// The first-bounce VPLs of lit proxy sides: for side `s` of proxy `i` with irradiance
/// `E` not zero, a [`VplKind::Surface`] VPL at the proxy facing that side, of flux `E ·
/// proxies.area`, with the proxy's object's material ([`surface_vpls`]). Also returns
/// each VPL's proxy.
pub fn proxy_vpls(
    scene: &Scene,
    proxies: &Proxies,
    irradiance: &[[Vec3; 2]],
) -> Result<(VplSet, Vec<u32>)> {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut e = Vec::new();
    let mut objects = Vec::new();
    let mut owner = Vec::new();
    for (i, sides) in irradiance.iter().enumerate() {
        for (side, &irr) in sides.iter().enumerate() {
            if irr.max_element() > 0.0 {
                let n = proxies.normal[i];
                positions.push(proxies.position[i].to_array());
                normals.push(if side == 0 { n } else { -n }.to_array());
                e.push(irr.to_array());
                objects.push(proxies.object[i]);
                owner.push(i as u32);
            }
        }
    }
    let areas = vec![proxies.area; positions.len()];
    let set = surface_vpls(scene, &positions, &normals, &e, &areas, &objects, true)?;
    Ok((set, owner))
}

/// First-bounce surface VPLs given by the caller (`vc.VPLs.from_surface`): at `positions`
/// with unit `normals` (normalised here; the side light leaves from), irradiance
/// `irradiance` (W/m² per channel, finite, `>= 0`) over `areas` (world units², finite,
/// `> 0`) and the material of object `objects[i]`. Each is a [`VplKind::Surface`] VPL of
/// flux `irradiance · area`, bounce 1, that arrived along its normal (exact for Lambert
/// surfaces; a glossy surface reflects it as light from straight above). `allow_empty`
/// lets the proxies of an unlit scene make an empty set. Fails naming the argument on bad
/// values.
pub fn surface_vpls(
    scene: &Scene,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    irradiance: &[[f32; 3]],
    areas: &[f32],
    objects: &[u32],
    allow_empty: bool,
) -> Result<VplSet> {
    let n = positions.len();
    crate::parallel::check_rows("normals", normals.len(), n, "positions")?;
    crate::parallel::check_rows("irradiance", irradiance.len(), n, "positions")?;
    crate::parallel::check_rows("areas", areas.len(), n, "positions")?;
    crate::parallel::check_rows("objects", objects.len(), n, "positions")?;
    if n == 0 && !allow_empty {
        return Err(Error::invalid("positions", "needs at least one VPL, got 0"));
    }
    let mesh = scene.mesh();
    let mut vpls = Vec::with_capacity(n);
    for i in 0..n {
        let (p, nrm) = checked_row(i, positions[i], normals[i], irradiance[i], "irradiance")?;
        if !(areas[i].is_finite() && areas[i] > 0.0) {
            return Err(Error::invalid(
                "areas",
                format!("row {i} must be finite and > 0, got {}", areas[i]),
            ));
        }
        let Some(object) = mesh.objects.get(objects[i] as usize) else {
            return Err(Error::invalid(
                "objects",
                format!(
                    "row {i} is object {}, but the scene has {} objects",
                    objects[i],
                    mesh.objects.len()
                ),
            ));
        };
        vpls.push(Vpl {
            position: p,
            origin: scene.offset_point(p, nrm),
            normal: nrm,
            incident: nrm,
            material: object.material,
            flux: Vec3::from(irradiance[i]) * areas[i],
            kind: VplKind::Surface,
            bounce: 1,
            light: u32::MAX,
        });
    }
    Ok(VplSet {
        vpls,
        disk_area: 0.0,
        fingerprint: scene.geometry_fingerprint(),
        stats: TraceStats::default(),
    })
}
