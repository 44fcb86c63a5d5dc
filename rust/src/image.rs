//! Image files: float RGB OpenEXR output shared by environment maps, renders and
//! experiments.

use std::path::Path;

use crate::error::{Error, Result};

use exr::prelude::{
    AttributeValue, Encoding, Image, Layer, LayerAttributes, SpecificChannels, Text, Vec2,
    WritableImage,
};

/// Writes `pixels` (row-major `y * width + x`, row 0 at the top) as a 32-bit float RGB
/// OpenEXR file with lossless ZIP compression. `layer` names the layer; `attributes` are
/// extra text attributes (name, value). Fails with [`Error::InvalidArgument`] when the
/// sizes disagree and [`Error::Io`] naming `path` when the file cannot be written.
pub fn write_exr_rgb(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
    layer: &str,
    attributes: &[(&str, &str)],
) -> Result<()> {
    if width == 0 || height == 0 || pixels.len() != width * height {
        return Err(Error::invalid(
            "image",
            format!(
                "{} pixels do not form a non-empty {width} x {height} image",
                pixels.len()
            ),
        ));
    }
    let mut layer_attributes = LayerAttributes::named(layer);
    layer_attributes.software_name = Some(Text::from("viscache_rs"));
    for (name, value) in attributes {
        layer_attributes
            .other
            .insert(Text::from(*name), AttributeValue::Text(Text::from(*value)));
    }
    let layer = Layer::new(
        (width, height),
        layer_attributes,
        Encoding::SMALL_LOSSLESS,
        SpecificChannels::rgb(|p: Vec2<usize>| {
            let [r, g, b] = pixels[p.y() * width + p.x()];
            (r, g, b)
        }),
    );
    crate::files::write_atomically(path, |temp| {
        Image::from_layer(layer)
            .write()
            .to_file(temp)
            .map_err(|e| match e {
                exr::error::Error::Io(source) => Error::Io {
                    path: path.to_path_buf(),
                    source,
                },
                other => Error::Io {
                    path: path.to_path_buf(),
                    source: std::io::Error::other(other.to_string()),
                },
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_reads_back_bit_exactly() {
        let dir = std::env::temp_dir().join(format!("viscache_image_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ramp.exr");
        let (w, h) = (5, 3);
        let pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| [i as f32 * 0.5, 1e6 / (1 + i) as f32, 0.0])
            .collect();
        write_exr_rgb(&path, w, h, &pixels, "image", &[("k", "v")]).unwrap();
        let image = exr::prelude::read_first_rgba_layer_from_file(
            &path,
            |res, _| vec![[0f32; 3]; res.width() * res.height()],
            move |px: &mut Vec<[f32; 3]>, p, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[p.y() * w + p.x()] = [r, g, b];
            },
        )
        .unwrap();
        assert_eq!(image.layer_data.channel_data.pixels, pixels);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn rejects_mismatched_sizes_and_bad_paths() {
        let p = Path::new("/nonexistent-dir/x.exr");
        assert!(matches!(
            write_exr_rgb(p, 2, 2, &[[0.0; 3]; 3], "image", &[]),
            Err(Error::InvalidArgument { .. })
        ));
        assert!(matches!(
            write_exr_rgb(p, 1, 1, &[[0.0; 3]], "image", &[]),
            Err(Error::Io { .. })
        ));
    }
}
