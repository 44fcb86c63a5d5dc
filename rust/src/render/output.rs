//! What a render by any registered method returns ([`super::registry`]): the image, its
//! variance, per-pixel sample counts and the method's figures as named values, so that the
//! bindings turn every method's result into Python the same way and a new method adds its
//! figures without a line in them.

use crate::camera::{Camera, GBuffer};

/// The view a render sees: a camera's pixels (the renderer traces their first hits) or a
/// G-buffer's hits (those very points are the pixels' anchors).
#[derive(Clone, Copy, Debug)]
pub enum View<'a> {
    Camera(&'a Camera),
    GBuffer(&'a GBuffer),
}

impl View<'_> {
    /// The camera of the view.
    pub fn camera(&self) -> &Camera {
        match self {
            View::Camera(c) => c,
            View::GBuffer(g) => &g.camera,
        }
    }
}

/// One figure of a render's stats.
#[derive(Clone, Debug, PartialEq)]
pub enum Stat {
    /// No value (a figure the run did not measure).
    None,
    Bool(bool),
    Int(u64),
    Float(f64),
    Text(&'static str),
    Ints(Vec<u64>),
    Floats(Vec<f64>),
    /// Named numbers (technique weights by technique, say).
    Named(Vec<(&'static str, f64)>),
}

impl From<bool> for Stat {
    fn from(v: bool) -> Self {
        Stat::Bool(v)
    }
}

impl From<u64> for Stat {
    fn from(v: u64) -> Self {
        Stat::Int(v)
    }
}

impl From<u32> for Stat {
    fn from(v: u32) -> Self {
        Stat::Int(v as u64)
    }
}

impl From<usize> for Stat {
    fn from(v: usize) -> Self {
        Stat::Int(v as u64)
    }
}

impl From<f64> for Stat {
    fn from(v: f64) -> Self {
        Stat::Float(v)
    }
}

impl From<f32> for Stat {
    fn from(v: f32) -> Self {
        Stat::Float(v as f64)
    }
}

impl From<&'static str> for Stat {
    fn from(v: &'static str) -> Self {
        Stat::Text(v)
    }
}

impl From<Vec<u64>> for Stat {
    fn from(v: Vec<u64>) -> Self {
        Stat::Ints(v)
    }
}

impl From<Vec<f64>> for Stat {
    fn from(v: Vec<f64>) -> Self {
        Stat::Floats(v)
    }
}

impl<T: Into<Stat>> From<Option<T>> for Stat {
    fn from(v: Option<T>) -> Self {
        v.map_or(Stat::None, Into::into)
    }
}

/// A render's figures, by name, in the order they were set (a name set twice keeps its
/// first place and its last value).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stats(Vec<(&'static str, Stat)>);

impl Stats {
    /// Sets figure `name`.
    pub fn set(&mut self, name: &'static str, value: impl Into<Stat>) {
        let value = value.into();
        match self.0.iter_mut().find(|(n, _)| *n == name) {
            Some(slot) => slot.1 = value,
            None => self.0.push((name, value)),
        }
    }

    /// Figure `name`, if set.
    pub fn get(&self, name: &str) -> Option<&Stat> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, v)| v)
    }

    /// Every figure, in order.
    pub fn iter(&self) -> impl Iterator<Item = &(&'static str, Stat)> {
        self.0.iter()
    }
}

/// A render by a registered method; `S`, its stats (named figures, or a method's own
/// struct where a caller reads them typed: [`super::Rendered`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOutput<S = Stats> {
    pub width: u32,
    pub height: u32,
    /// Mean radiance per pixel, row-major, row 0 at the top.
    pub image: Vec<[f32; 3]>,
    /// Per-pixel variance of the mean, per channel (infinite below two samples).
    pub variance: Vec<[f32; 3]>,
    /// The control variate's per-pixel `α`, for the methods that have one.
    pub alpha: Option<Vec<[f32; 3]>>,
    /// Samples each pixel took, row-major.
    pub sample_counts: Vec<u32>,
    /// The method's figures.
    pub stats: S,
}

impl<S> RenderOutput<S> {
    /// The same image with its stats turned into `T` by `f`.
    pub fn map_stats<T>(self, f: impl FnOnce(S) -> T) -> RenderOutput<T> {
        RenderOutput {
            width: self.width,
            height: self.height,
            image: self.image,
            variance: self.variance,
            alpha: self.alpha,
            sample_counts: self.sample_counts,
            stats: f(self.stats),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_keep_their_order_and_the_last_value() {
        let mut s = Stats::default();
        s.set("a", 1u32);
        s.set("b", Some(2.5f64));
        s.set("c", None::<u64>);
        s.set("a", true);
        let names: Vec<_> = s.iter().map(|(n, _)| *n).collect();
        assert_eq!(names, ["a", "b", "c"]);
        assert_eq!(s.get("a"), Some(&Stat::Bool(true)));
        assert_eq!(s.get("b"), Some(&Stat::Float(2.5)));
        assert_eq!(s.get("c"), Some(&Stat::None));
        assert_eq!(s.get("d"), None);
    }
}
