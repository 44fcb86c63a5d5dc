//! Mixed proxies (BLD §5's "mixed proxies", Table 4): per object, the proxy whose
//! guarantee holds for it.

use super::clustered::check_cell;
use super::hull::hull_triangles;
use super::inscribed::{check_watertight, inscribed_spheres, tessellate, unit_sphere};
use super::{box_triangles, per_object, ProxyKind, ProxyOptions, ProxySet};
use crate::error::Result;
use crate::geometry::{Bounds, Scene};

impl ProxySet {
    /// Mixed proxies: per object of `parent` (`options.objects`, or every object with
    /// triangles), `options.spheres` inscribed spheres when it is watertight (inside)
    /// and, when not, its hull cut to `options.target` triangles with `options.hull`,
    /// else its box (outside). The set as a whole has neither guarantee: kind general.
    /// Errors name `spheres`, `target`, `cell` and `objects`.
    pub fn mixed(parent: &Scene, options: &ProxyOptions) -> Result<Self> {
        options.validate()?;
        check_cell(options.cell)?;
        if options.hull {
            if let Some(t) = options.target {
                if t < super::hull::MIN_HULL_TARGET {
                    // Same message as the hull builder.
                    return ProxySet::hulls(parent, options.objects.as_deref(), Some(t));
                }
            }
        }
        let ball = unit_sphere();
        per_object(
            parent,
            options.objects.as_deref(),
            ProxyKind::General,
            |o, triangles| {
                if triangles.is_empty() {
                    return Ok(None);
                }
                if let Ok(welded) = check_watertight(o, triangles) {
                    let spheres = inscribed_spheres(triangles, &welded, options.spheres);
                    if !spheres.is_empty() {
                        return Ok(Some(tessellate(&spheres, &ball)));
                    }
                }
                Ok(if options.hull {
                    hull_triangles(triangles, options.target)
                } else {
                    Some(box_triangles(&Bounds::of_triangles(triangles)).to_vec())
                })
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::proxies::build;
    use crate::geometry::proxies::test_meshes::*;
    use glam::Vec3;

    #[test]
    fn mixed_sets_give_closed_objects_spheres_and_open_ones_boxes() {
        let ball = bumpy_ball(3, Vec3::ZERO, 1.0, 0.2);
        let mut open = bumpy_ball(3, Vec3::new(4.0, 0.0, 0.0), 1.0, 0.2);
        open.truncate(600);
        let scene = scene_of(&[ball.clone(), open.clone()]);
        let options = ProxyOptions {
            spheres: 10,
            ..ProxyOptions::DEFAULT
        };
        let set = build(&scene, "mixed", &options).unwrap();
        assert_eq!(set.kind(), ProxyKind::General);
        assert_eq!(set.objects(), &[0, 1]);
        let inner = proxy_triangles(&set, 0);
        assert_eq!(inner.len(), 800);
        assert!(points_on(&inner)
            .iter()
            .all(|&p| inside_by_parity(&ball, p)));
        assert_eq!(
            proxy_triangles(&set, 1),
            box_triangles(&Bounds::of_triangles(&open)).to_vec()
        );
        let hulled = build(
            &scene,
            "mixed",
            &ProxyOptions {
                hull: true,
                target: Some(20),
                ..options.clone()
            },
        )
        .unwrap();
        let n = proxy_triangles(&hulled, 1).len();
        assert!(n > 12 && n <= 20, "{n}");
        let err = build(
            &scene,
            "mixed",
            &ProxyOptions {
                hull: true,
                target: Some(4),
                ..options
            },
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("target"), "{err}");
    }
}
