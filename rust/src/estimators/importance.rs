//! Importance caching for many lights (survey `004_d2289ee9e28a0f98.txt` ch. 6, after
//! Georgiev et al. 2012): records at sparse points hold, per light, distributions a
//! shading point draws its lights from; the cache shapes the pdf only, so the estimate
//! (eq. 6.2) stays unbiased for the light set.
//!
//! Here so far: [`combine`], how the rows of the records near a shading point become one
//! estimator — the balance heuristic over the records of a row (eq. 6.4–6.5) and the
//! α-max heuristic (eq. 6.6) or the balance heuristic over the rows F, U, B, C; and
//! [`bound`], row B's geometry term over a record's region (Fig. 6.5). The records
//! themselves (their build on a G-buffer grid) and the render method come next.

pub mod bound;
pub mod combine;
