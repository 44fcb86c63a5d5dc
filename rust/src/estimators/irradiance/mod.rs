//! Irradiance caching with gradients (Survey ch. 3, `004_d2289ee9e28a0f98.txt`; Ward et
//! al. 1988, Ward & Heckbert 1992): one-bounce irradiance estimated at sparse records by
//! stratified hemisphere sampling (eq. 3.1–3.4, [`record`]), kept with its validity radius
//! and gradients (eq. 3.5–3.6), and interpolated between records (eq. 3.7–3.8, [`cache`]).
//! Biased: what the records miss between them is error, measured against the one-bounce
//! reference ([`crate::estimators::indirect`]).

pub mod build;
pub mod cache;
pub mod io;
pub mod record;
