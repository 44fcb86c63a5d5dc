//! `viscache_rs._core.write_exr`: float RGB OpenEXR output of [`crate::image`].

use std::path::PathBuf;

use pyo3::prelude::*;

use super::convert::{image3_f32, IntoPyResult};

/// Writes an (H, W, 3) image of reals as a float32 RGB OpenEXR file (lossless).
#[pyfunction]
pub fn write_exr(py: Python<'_>, path: PathBuf, image: &Bound<'_, PyAny>) -> PyResult<()> {
    let (pixels, h, w) = image3_f32(image, "image")?;
    // The EXR encoder allocates its blocks internally; a worst case of another copy of
    // the image, probed first, makes a size that cannot be met a MemoryError.
    crate::alloc::check_memory(crate::alloc::bytes_of::<[f32; 3]>(pixels.len()), "image").py()?;
    py.detach(|| crate::image::write_exr_rgb(&path, w, h, &pixels, "image", &[]))
        .py()
}
