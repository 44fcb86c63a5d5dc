//! Geometry proxies (BLD §3, `002_f6f7ae5fac667f5c.txt`): cheap stand-ins `P'` for a
//! scene's objects `P`, traced by the stochastic visibility estimator
//! (`estimators::stochastic_visibility`) in place of, or beside, the scene.
//!
//! A proxy set is its own [`Scene`] (its own BVH, built by the scene's builders), never a
//! copy of the scene it stands for. It remembers that scene by its geometry fingerprint
//! and states one guarantee ([`ProxyKind`]) for all its triangles.

use crate::error::{Error, Result};
use glam::Vec3;

mod clustered;
mod hull;
mod inscribed;
mod mixed;

use crate::geometry::{Bounds, BuildQuality, Mesh, Scene};

/// What a proxy set guarantees about the geometry it stands for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProxyKind {
    /// Encloses every triangle (a bounding box, a convex hull): no ray hits `P` without
    /// hitting `P'`, so type 2 never occurs and `p3` may be 0 (eq. 17–18). Outside proxies
    /// are solid: a segment that starts or ends inside one counts as hitting it.
    Outside,
    /// Lies inside a watertight mesh: no ray hits `P'` without hitting `P`, so type 3
    /// never occurs and `p2` may be 0 (eq. 19–20).
    Inside,
    /// Neither: every term is needed.
    General,
}

impl ProxyKind {
    /// Every kind, in the order the errors list them.
    pub const ALL: [ProxyKind; 3] = [ProxyKind::Outside, ProxyKind::Inside, ProxyKind::General];

    /// The name `kind=` takes.
    pub const fn name(self) -> &'static str {
        match self {
            ProxyKind::Outside => "outside",
            ProxyKind::Inside => "inside",
            ProxyKind::General => "general",
        }
    }

    /// The kind called `name`; an error naming `kind` otherwise.
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                Error::invalid(
                    "kind",
                    format!(
                        "expected one of {:?}, got {name:?}",
                        Self::ALL.map(|k| k.name())
                    ),
                )
            })
    }
}

/// How [`build`] makes a proxy set; Python's `vc.Proxies.build` takes the same names as
/// keyword arguments.
#[derive(Clone, Debug, PartialEq)]
pub struct ProxyOptions {
    /// Outside proxies (and the outside part of `mixed`): the convex hull of each object
    /// instead of its axis-aligned box.
    pub hull: bool,
    /// Triangle budget per object: for hulls, an enclosing polytope of at most `target`
    /// triangles (>= 12); for `general`, the vertex-clustering cell is grown until the
    /// object's proxy has at most `target` triangles (>= 1). `None`: no budget.
    pub target: Option<usize>,
    /// Inscribed spheres per watertight object (`inside`, `mixed`), 1..=4096.
    pub spheres: usize,
    /// Vertex-clustering cell side as a fraction of the object's largest box side
    /// (`general`), in (0, 1]; BLD §5 uses 0.03.
    pub cell: f32,
    /// Ids of the stood-for objects; `None`: every object with triangles.
    pub objects: Option<Vec<u32>>,
}

impl ProxyOptions {
    /// Boxes, 40 spheres per object (BLD §5's dragons), cells of 3% (BLD §5), all objects.
    pub const DEFAULT: Self = Self {
        hull: false,
        target: None,
        spheres: 40,
        cell: 0.03,
        objects: None,
    };

    /// Fails, naming the argument, on a value out of range.
    pub fn validate(&self) -> Result<()> {
        if let Some(t) = self.target {
            if t == 0 {
                return Err(Error::invalid(
                    "target",
                    "must be at least 1 triangle, got 0",
                ));
            }
        }
        if self.spheres == 0 || self.spheres > MAX_SPHERES {
            return Err(Error::invalid(
                "spheres",
                format!("must lie in [1, {MAX_SPHERES}], got {}", self.spheres),
            ));
        }
        clustered::check_cell(self.cell)?;
        Ok(())
    }
}

impl Default for ProxyOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Most inscribed spheres one object may get.
pub const MAX_SPHERES: usize = 4096;

/// The proxy set of `kind` (`"outside"`, `"inside"`, `"general"` or `"mixed"`) for
/// `parent`'s objects, made as `options` says:
/// - `outside`: [`ProxySet::boxes`], or [`ProxySet::hulls`] with `hull`;
/// - `inside`: [`ProxySet::inscribed`] (every object must be watertight);
/// - `general`: [`ProxySet::clustered`] (with `target`: [`ProxySet::clustered_to`]);
/// - `mixed`: [`ProxySet::mixed`].
///
/// Errors name the argument: `kind`, `target`, `spheres`, `cell`, `objects`.
pub fn build(parent: &Scene, kind: &str, options: &ProxyOptions) -> Result<ProxySet> {
    const KINDS: [&str; 4] = ["outside", "inside", "general", "mixed"];
    if !KINDS.contains(&kind) {
        return Err(Error::invalid(
            "kind",
            format!("expected one of {KINDS:?}, got {kind:?}"),
        ));
    }
    options.validate()?;
    let objects = options.objects.as_deref();
    match kind {
        "outside" if options.hull => ProxySet::hulls(parent, objects, options.target),
        "outside" => {
            if options.target.is_some() {
                return Err(Error::invalid(
                    "target",
                    "a box has 12 triangles: give target with hull=True or kind='general'",
                ));
            }
            ProxySet::boxes(parent, objects)
        }
        "inside" => ProxySet::inscribed(parent, objects, options.spheres),
        "general" => match options.target {
            Some(t) => ProxySet::clustered_to(parent, objects, t),
            None => ProxySet::clustered(parent, objects, options.cell),
        },
        _ => ProxySet::mixed(parent, options),
    }
}

/// The stood-for object ids: `objects`, checked against `parent`, or every object with
/// triangles. Errors name `objects` for an id the scene lacks or one given twice.
fn object_ids(parent: &Scene, objects: Option<&[u32]>) -> Result<Vec<u32>> {
    let mesh = parent.mesh();
    let Some(ids) = objects else {
        return Ok((0..mesh.objects.len() as u32)
            .filter(|&o| mesh.objects[o as usize].num_triangles > 0)
            .collect());
    };
    for (i, &o) in ids.iter().enumerate() {
        if o as usize >= mesh.objects.len() {
            return Err(Error::invalid(
                "objects",
                format!(
                    "the scene has {} objects, no object {o}",
                    mesh.objects.len()
                ),
            ));
        }
        if ids[..i].contains(&o) {
            return Err(Error::invalid(
                "objects",
                format!("object {o} is given twice"),
            ));
        }
    }
    Ok(ids.to_vec())
}

/// The triangles of `parent`'s object `o` (an id checked by [`object_ids`]).
fn object_triangles(parent: &Scene, o: u32) -> &[[Vec3; 3]] {
    let mesh = parent.mesh();
    &mesh.triangles[mesh.objects[o as usize].triangle_range()]
}

/// One proxy mesh per object from `make` (run in parallel over objects; `None` for an
/// object that gets no proxy), gathered into a set of `kind`. The first error, in object
/// order, wins.
fn per_object(
    parent: &Scene,
    objects: Option<&[u32]>,
    kind: ProxyKind,
    make: impl Fn(u32, &[[Vec3; 3]]) -> Result<Option<Vec<[Vec3; 3]>>> + Sync,
) -> Result<ProxySet> {
    use rayon::prelude::*;
    let ids = object_ids(parent, objects)?;
    let made: Vec<Result<Option<Vec<[Vec3; 3]>>>> = ids
        .par_iter()
        .map(|&o| make(o, object_triangles(parent, o)))
        .collect();
    let mut meshes = Vec::with_capacity(ids.len());
    for (&o, m) in ids.iter().zip(made) {
        if let Some(triangles) = m? {
            let mut mesh = Mesh::new();
            mesh.add_triangles(triangles, Default::default(), None)?;
            meshes.push((o, mesh));
        }
    }
    ProxySet::from_meshes(parent, kind, meshes)
}

/// A proxy set: triangles standing for some of a scene's objects, with one guarantee.
///
/// Invariants: `scene`'s BVH is built; object `i` of `scene` stands for object
/// `objects[i]` of the scene whose geometry fingerprint is `built_for`.
#[derive(Clone, Debug)]
pub struct ProxySet {
    kind: ProxyKind,
    scene: Scene,
    objects: Vec<u32>,
    built_for: u64,
}

impl ProxySet {
    /// A proxy set of `kind` from user-made meshes, one per stood-for object of `parent`
    /// (`(object id in parent, mesh)`): the guarantee is taken on trust (see the builders
    /// for sets that check it). Errors name `objects` for an id `parent` lacks or given
    /// twice.
    pub fn from_meshes(parent: &Scene, kind: ProxyKind, meshes: Vec<(u32, Mesh)>) -> Result<Self> {
        let mut objects = Vec::with_capacity(meshes.len());
        let mut all = Mesh::new();
        for (object, mesh) in meshes {
            if object as usize >= parent.num_objects() {
                return Err(Error::invalid(
                    "objects",
                    format!(
                        "the scene has {} objects, no object {object}",
                        parent.num_objects()
                    ),
                ));
            }
            if objects.contains(&object) {
                return Err(Error::invalid(
                    "objects",
                    format!("object {object} has two proxies"),
                ));
            }
            objects.push(object);
            let triangles = mesh.triangles;
            all.add_triangles(triangles, Default::default(), None)?;
        }
        let mut scene = Scene::from_mesh(all);
        scene.build(BuildQuality::default());
        Ok(Self {
            kind,
            scene,
            objects,
            built_for: parent.geometry_fingerprint(),
        })
    }

    /// Outside proxies as one axis-aligned box (12 triangles) per object of `parent`
    /// (`objects`, or every object with triangles when `None`); errors name `objects` for
    /// an id the scene lacks.
    pub fn boxes(parent: &Scene, objects: Option<&[u32]>) -> Result<Self> {
        per_object(parent, objects, ProxyKind::Outside, |_, triangles| {
            let b = Bounds::of_triangles(triangles);
            Ok((!b.is_empty()).then(|| box_triangles(&b).to_vec()))
        })
    }

    /// Its guarantee.
    pub fn kind(&self) -> ProxyKind {
        self.kind
    }

    /// The proxies as a scene (BVH built): trace it as any scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// For proxy object `i`, the id of the object it stands for in the parent scene.
    pub fn objects(&self) -> &[u32] {
        &self.objects
    }

    /// The geometry fingerprint of the scene the set was built for.
    pub fn built_for(&self) -> u64 {
        self.built_for
    }

    /// Fails, naming `proxies`, when `scene` is not the one the set was built for.
    pub fn check_scene(&self, scene: &Scene) -> Result<()> {
        if scene.geometry_fingerprint() != self.built_for {
            return Err(Error::invalid(
                "proxies",
                "the proxy set was built for another scene",
            ));
        }
        Ok(())
    }

    /// Number of proxy triangles.
    pub fn num_triangles(&self) -> usize {
        self.scene.num_triangles()
    }
}

/// The 12 triangles of a box's surface, outward-facing.
pub fn box_triangles(b: &Bounds) -> [[Vec3; 3]; 12] {
    let c = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        )
    };
    // Each face as a quad of corner indices, counter-clockwise seen from outside.
    const FACES: [[usize; 4]; 6] = [
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
    ];
    let mut out = [[Vec3::ZERO; 3]; 12];
    for (f, q) in FACES.iter().enumerate() {
        out[2 * f] = [c(q[0]), c(q[1]), c(q[2])];
        out[2 * f + 1] = [c(q[0]), c(q[2]), c(q[3])];
    }
    out
}

/// Meshes and brute-force checks shared by the builders' tests.
#[cfg(test)]
pub(crate) mod test_meshes {
    use glam::{DVec3, Vec3};

    use crate::geometry::Scene;

    /// A closed, bumpy sphere: an icosahedron subdivided `level` times (20 * 4^level
    /// triangles), each vertex at `radius * (1 + amp * bump(direction))` from `centre`.
    pub fn bumpy_ball(level: u32, centre: Vec3, radius: f32, amp: f32) -> Vec<[Vec3; 3]> {
        let mut tris = super::inscribed::unit_sphere();
        for _ in 1..level {
            tris = tris
                .iter()
                .flat_map(|&[a, b, c]| {
                    let (ab, bc, ca) = (
                        (a + b).normalize(),
                        (b + c).normalize(),
                        (c + a).normalize(),
                    );
                    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
                })
                .collect();
        }
        let bump = |d: DVec3| (3.0 * d.x).sin() * (2.0 * d.y + 1.0).sin() * (4.0 * d.z).cos();
        tris.iter()
            .map(|t| {
                t.map(|d| centre + (d * radius as f64 * (1.0 + amp as f64 * bump(d))).as_vec3())
            })
            .collect()
    }

    /// A scene of one object per triangle list.
    pub fn scene_of(objects: &[Vec<[Vec3; 3]>]) -> Scene {
        let mut mesh = crate::geometry::Mesh::new();
        for t in objects {
            mesh.add_triangles(t.iter().copied(), Default::default(), None)
                .unwrap();
        }
        Scene::from_mesh(mesh)
    }

    /// True when `p` is inside the closed surface `tris`: odd crossings of a ray in a
    /// fixed, oddly tilted direction (f64 Möller–Trumbore, brute force).
    pub fn inside_by_parity(tris: &[[Vec3; 3]], p: Vec3) -> bool {
        let o = p.as_dvec3();
        let d = DVec3::new(0.5773, 0.6180, 0.5335).normalize();
        let mut crossings = 0;
        for t in tris {
            let [a, b, c] = t.map(|v| v.as_dvec3());
            let (e1, e2) = (b - a, c - a);
            let q = d.cross(e2);
            let det = e1.dot(q);
            if det.abs() < 1e-300 {
                continue;
            }
            let s = o - a;
            let u = s.dot(q) / det;
            let r = s.cross(e1);
            let v = d.dot(r) / det;
            let t = e2.dot(r) / det;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0 {
                crossings += 1;
            }
        }
        crossings % 2 == 1
    }

    /// The triangles of proxy object `i` of `set`.
    pub fn proxy_triangles(set: &super::ProxySet, i: usize) -> Vec<[Vec3; 3]> {
        let mesh = set.scene().mesh();
        mesh.triangles[mesh.objects[i].triangle_range()].to_vec()
    }

    /// A few points spread over each triangle (corners pulled in, centroid).
    pub fn points_on(tris: &[[Vec3; 3]]) -> Vec<Vec3> {
        let w = [
            [0.98, 0.01, 0.01],
            [0.01, 0.98, 0.01],
            [0.01, 0.01, 0.98],
            [1.0 / 3.0; 3],
            [0.6, 0.3, 0.1],
        ];
        tris.iter()
            .flat_map(|t| {
                w.iter()
                    .map(move |w| t[0] * w[0] + t[1] * w[1] + t[2] * w[2])
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_triangles_face_outwards_and_cover_the_surface() {
        let b = Bounds {
            min: Vec3::new(-1.0, -2.0, 0.5),
            max: Vec3::new(2.0, 1.0, 3.0),
        };
        let centre = (b.min + b.max) * 0.5;
        let mut area = 0.0;
        for t in box_triangles(&b) {
            let n = (t[1] - t[0]).cross(t[2] - t[0]);
            area += 0.5 * n.length();
            let mid = (t[0] + t[1] + t[2]) / 3.0;
            assert!(n.dot(mid - centre) > 0.0, "{t:?} faces inwards");
        }
        let e = b.max - b.min;
        let want = 2.0 * (e.x * e.y + e.y * e.z + e.z * e.x);
        assert!((area - want).abs() < 1e-4 * want, "{area} vs {want}");
    }

    #[test]
    fn boxes_enclose_each_object_and_refuse_unknown_ids() {
        let mut scene = Scene::new();
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]];
        scene
            .add_indexed(&v, &[[0, 1, 2]], Default::default(), None)
            .unwrap();
        let set = ProxySet::boxes(&scene, None).unwrap();
        assert_eq!(set.kind(), ProxyKind::Outside);
        assert_eq!(set.num_triangles(), 12);
        assert_eq!(set.objects(), &[0]);
        set.check_scene(&scene).unwrap();
        let err = ProxySet::boxes(&scene, Some(&[3])).unwrap_err();
        assert!(err.to_string().contains("objects"), "{err}");
        let mut other = scene.clone();
        other
            .add_indexed(&v, &[[0, 2, 1]], Default::default(), None)
            .unwrap();
        assert!(set.check_scene(&other).is_err());
    }

    #[test]
    fn build_names_the_bad_argument() {
        let mut scene = Scene::new();
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]];
        scene
            .add_indexed(&v, &[[0, 1, 2]], Default::default(), None)
            .unwrap();
        let d = ProxyOptions::DEFAULT;
        let set = build(&scene, "outside", &d).unwrap();
        assert_eq!(set.num_triangles(), 12);
        let cases: [(&str, ProxyOptions, &str); 8] = [
            ("box", d.clone(), "kind"),
            (
                "outside",
                ProxyOptions {
                    target: Some(0),
                    hull: true,
                    ..d.clone()
                },
                "target",
            ),
            (
                "outside",
                ProxyOptions {
                    target: Some(20),
                    ..d.clone()
                },
                "target",
            ),
            (
                "inside",
                ProxyOptions {
                    spheres: 0,
                    ..d.clone()
                },
                "spheres",
            ),
            (
                "inside",
                ProxyOptions {
                    spheres: MAX_SPHERES + 1,
                    ..d.clone()
                },
                "spheres",
            ),
            (
                "general",
                ProxyOptions {
                    cell: 0.0,
                    ..d.clone()
                },
                "cell",
            ),
            (
                "general",
                ProxyOptions {
                    cell: f32::NAN,
                    ..d.clone()
                },
                "cell",
            ),
            (
                "outside",
                ProxyOptions {
                    objects: Some(vec![0, 0]),
                    ..d.clone()
                },
                "objects",
            ),
        ];
        for (kind, options, name) in cases {
            let err = build(&scene, kind, &options).unwrap_err();
            assert!(
                err.to_string().starts_with(name),
                "{kind} {options:?}: {err}"
            );
        }
        let err = build(
            &scene,
            "general",
            &ProxyOptions {
                cell: 1.5,
                ..d.clone()
            },
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("cell"), "{err}");
    }
}
