//! EXR files of environment maps (the `exr` crate), in the octahedral or lat-long layout.

use std::path::Path;

use super::{check_resolution, EnvMap, MAX_EQUIRECT_SIDE, MAX_RESOLUTION};
use crate::error::{Error, Result};

/// Name of the EXR header attribute that records the layout.
pub const EXR_LAYOUT_ATTRIBUTE: &str = "viscacheLayout";
/// How [`EnvMap::to_exr`] lays the map out in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExrLayout {
    /// The `res x res` octahedral texture itself (bit-exact).
    Octahedral,
    /// A `2res x res` lat-long image, resampled with [`EnvMap::to_equirect`].
    LatLong,
}

impl ExrLayout {
    /// The layout's name: `"octahedral"` or `"latlong"`.
    pub fn name(self) -> &'static str {
        match self {
            ExrLayout::Octahedral => "octahedral",
            ExrLayout::LatLong => "latlong",
        }
    }

    /// Parses `"octahedral"` or `"latlong"` (also `"lat-long"`, `"equirect"`,
    /// `"equirectangular"`), case-insensitively; `name` is the argument named on error.
    pub fn parse(value: &str, name: &str) -> Result<Self> {
        match value.to_ascii_lowercase().as_str() {
            "octahedral" => Ok(ExrLayout::Octahedral),
            "latlong" | "lat-long" | "equirect" | "equirectangular" => Ok(ExrLayout::LatLong),
            _ => Err(Error::invalid(
                name,
                format!("unknown layout {value:?}; expected \"octahedral\" or \"latlong\""),
            )),
        }
    }
}
/// Largest EXR image side accepted on reading (guards against corrupt headers).
const MAX_EXR_SIDE: usize = MAX_EQUIRECT_SIDE;

fn parse_error(path: &Path, reason: impl Into<String>) -> Error {
    Error::Parse {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Maps an `exr` error to the crate's: missing or unreadable files are [`Error::Io`],
/// malformed or unsupported contents (including truncation) [`Error::Parse`].
fn exr_error(path: &Path, e: exr::error::Error) -> Error {
    use exr::error::Error as E;
    match e {
        E::Io(source)
            if !matches!(
                source.kind(),
                std::io::ErrorKind::UnexpectedEof | std::io::ErrorKind::InvalidData
            ) =>
        {
            Error::Io {
                path: path.to_path_buf(),
                source,
            }
        }
        E::Io(source) => parse_error(path, format!("not a valid OpenEXR file ({source})")),
        E::NotSupported(what) => parse_error(path, format!("unsupported OpenEXR feature: {what}")),
        E::Invalid(what) => parse_error(path, format!("not a valid OpenEXR file: {what}")),
        E::Aborted => parse_error(path, "reading was aborted"),
    }
}

impl EnvMap {
    /// Reads an environment map from an OpenEXR file (see the module docs for how the
    /// layout is decided). A lat-long image becomes an octahedral map of side
    /// `min(4096, next_power_of_two(height))`; use [`Self::read_exr`] to choose.
    pub fn from_exr(path: impl AsRef<Path>) -> Result<EnvMap> {
        Self::read_exr(path, None)
    }

    /// [`Self::from_exr`] with the octahedral `resolution` to convert to (`None`: an
    /// octahedral file keeps its own, a lat-long file gets
    /// `min(4096, next_power_of_two(height))`). Missing or unreadable files are
    /// [`Error::Io`]; corrupt files, unknown layouts and bad pixel values [`Error::Parse`],
    /// all naming the path.
    pub fn read_exr(path: impl AsRef<Path>, resolution: Option<u32>) -> Result<EnvMap> {
        use exr::prelude::*;
        let path = path.as_ref();
        if let Some(r) = resolution {
            check_resolution(r, "resolution")?;
        }
        // Open once ourselves so a missing file is a plain I/O error.
        std::fs::File::open(path).map_err(|source| crate::error::Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        // Check the size from the header before allocating pixels.
        let meta =
            exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(path, e))?;
        let header = meta
            .headers
            .first()
            .ok_or_else(|| parse_error(path, "the file has no layers"))?;
        let size = header.layer_size;
        if size.width() == 0
            || size.height() == 0
            || size.width() > MAX_EXR_SIDE
            || size.height() > MAX_EXR_SIDE
        {
            return Err(parse_error(
                path,
                format!(
                    "image of {} x {} pixels; sides must be in [1, {MAX_EXR_SIDE}]",
                    size.width(),
                    size.height()
                ),
            ));
        }
        let channels: Vec<String> = header
            .channels
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        let has = |want: &str| {
            channels.iter().any(|c| {
                c.rsplit('.')
                    .next()
                    .is_some_and(|n| n.eq_ignore_ascii_case(want))
            })
        };
        if !(has("R") && has("G") && has("B")) {
            return Err(parse_error(
                path,
                format!("has channels {channels:?}; an environment map needs R, G and B"),
            ));
        }
        let read = std::panic::catch_unwind(|| {
            read()
                .no_deep_data()
                .largest_resolution_level()
                .rgba_channels(
                    |size, _| {
                        (
                            size.width(),
                            vec![[0.0f32; 3]; size.width() * size.height()],
                        )
                    },
                    |(w, pixels): &mut (usize, Vec<[f32; 3]>),
                     p: Vec2<usize>,
                     (r, g, b, _a): (f32, f32, f32, f32)| {
                        pixels[p.y() * *w + p.x()] = [r, g, b];
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .from_file(path)
        })
        .map_err(|_| parse_error(path, "the OpenEXR decoder failed on this file"))?
        .map_err(|e| exr_error(path, e))?;
        let (width, pixels) = read.layer_data.channel_data.pixels;
        let height = pixels.len() / width.max(1);
        let attribute = read
            .attributes
            .other
            .get(&Text::from(EXR_LAYOUT_ATTRIBUTE))
            .or_else(|| {
                read.layer_data
                    .attributes
                    .other
                    .get(&Text::from(EXR_LAYOUT_ATTRIBUTE))
            })
            .map(|v| match v {
                AttributeValue::Text(t) => t.to_string(),
                _ => String::new(),
            });
        let layout = match attribute.as_deref() {
            Some(name) => ExrLayout::parse(name, EXR_LAYOUT_ATTRIBUTE)
                .map_err(|e| parse_error(path, e.to_string()))?,
            None if width == height && width.is_power_of_two() => ExrLayout::Octahedral,
            None if width == 2 * height => ExrLayout::LatLong,
            None => {
                return Err(parse_error(
                    path,
                    format!(
                        "cannot tell the layout of a {width} x {height} image: expected a \
                         square octahedral map with a power-of-two side or a 2:1 lat-long \
                         image (or the {EXR_LAYOUT_ATTRIBUTE} attribute)"
                    ),
                ))
            }
        };
        // The decoder above cannot be stopped part-way (the `exr` crate has no hook for
        // it); the conversion below polls the current stop and stays an interruption.
        let as_parse = |e: crate::error::Error| match e {
            e @ crate::error::Error::Interrupted { .. } => e,
            e => parse_error(path, e.to_string()),
        };
        crate::stop::Stop::current().check("EnvMap.from_exr")?;
        match layout {
            ExrLayout::Octahedral => {
                if width != height || !width.is_power_of_two() || width > MAX_RESOLUTION as usize {
                    return Err(parse_error(
                        path,
                        format!(
                            "an octahedral map must be square with a power-of-two side of at \
                             most {MAX_RESOLUTION}, got {width} x {height}"
                        ),
                    ));
                }
                let map = Self::from_octahedral(width as u32, pixels).map_err(as_parse)?;
                match resolution {
                    Some(r) => map.resampled(r),
                    None => Ok(map),
                }
            }
            ExrLayout::LatLong => {
                let r = resolution
                    .unwrap_or_else(|| (height.next_power_of_two() as u32).min(MAX_RESOLUTION));
                Self::from_equirect(&pixels, width, height, r).map_err(as_parse)
            }
        }
    }

    /// Writes the map to an OpenEXR file: `f32` RGB, lossless ZIP compression, with the
    /// `viscacheLayout` attribute. [`ExrLayout::Octahedral`] writes the texture as is
    /// (it reads back bit-exactly); [`ExrLayout::LatLong`] writes a `2res x res` image from
    /// [`Self::to_equirect`]. Failures are [`Error::Io`] naming the path.
    pub fn to_exr(&self, path: impl AsRef<Path>, layout: ExrLayout) -> Result<()> {
        let res = self.resolution as usize;
        let (width, height, pixels) = match layout {
            ExrLayout::Octahedral => (res, res, self.texels.clone()),
            ExrLayout::LatLong => (2 * res, res, self.to_equirect(2 * res, res)?),
        };
        crate::image::write_exr_rgb(
            path.as_ref(),
            width,
            height,
            &pixels,
            "envmap",
            &[(EXR_LAYOUT_ATTRIBUTE, layout.name())],
        )
    }
}
