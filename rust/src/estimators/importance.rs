//! Importance caching for many lights (survey `004_d2289ee9e28a0f98.txt` ch. 6, after
//! Georgiev et al. 2012): records at sparse points hold, per light, distributions a
//! shading point draws its lights from; the cache shapes the pdf only, so the estimate
//! (eq. 6.2) stays unbiased for the light set.
//!
//! Here so far: [`combine`], how the rows of the records near a shading point become one
//! estimator — the balance heuristic over the records of a row (eq. 6.4–6.5) and the
//! α-max heuristic (eq. 6.6) or the balance heuristic over the rows F, U, B, C; and
//! [`bound`], row B's geometry term over a record's region (Fig. 6.5); [`records`], the
//! records (rows F, U, B per light), their index and lookup (eq. 6.3); [`build`], their
//! build on a view's G-buffer (Algorithm 12). The render method is `render::importance`.

pub mod bound;
pub mod build;
pub mod combine;
pub mod io;
pub mod records;
