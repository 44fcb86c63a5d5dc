//! Light sources: area lights made of triangles.

pub mod area;
