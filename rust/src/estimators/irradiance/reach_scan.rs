//! Reach queries as a linear scan over the records: correct, `O(records)` per lookup. The
//! record index's own query by per-node reach (issue 62 §2) replaces it when it lands.
use glam::Vec3;

use crate::spatial::{Records, SpatialIndex};

impl<S: Records> SpatialIndex<S> {
    /// Every record whose reach covers `x`, `(id, d²)` in id order.
    pub fn within_reach(&self, x: Vec3, out: &mut Vec<(u32, f32)>) {
        for id in 0..self.len() {
            let (p, _) = self.site(id);
            let d2 = p.distance_squared(x);
            let r = self.records().radius(id);
            if d2.sqrt() < r {
                out.push((id as u32, d2));
            }
        }
    }

    /// Every record within `r` of `x` (`|x − p| < r`), `(id, d²)` in id order.
    pub fn within_radius(&self, x: Vec3, r: f32, out: &mut Vec<(u32, f32)>) {
        for id in 0..self.len() {
            let (p, _) = self.site(id);
            let d2 = p.distance_squared(x);
            if d2.sqrt() < r {
                out.push((id as u32, d2));
            }
        }
    }
}
