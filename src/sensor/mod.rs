//! The sensor: a perspective camera, the film it exposes and the reconstruction filter.
//! Parameters and conventions follow Mitsuba 3's `perspective`, `hdrfilm` and `rfilter` plugins so that
//! one scene file gives the same image in both renderers.

mod camera;
mod rfilter;

pub use camera::PerspectiveCamera;
pub use rfilter::ReconstructionFilter;

use crate::props::{Props, SceneError};

/// Memory a render keeps per film pixel, for refusing films that cannot fit: the film's sums, squared
/// sums, counts and splats (80 bytes, `render::Film`), the resolved image and one output copy (12
/// bytes each), with headroom for layers and per-thread tiles. A test in `render` keeps it honest.
pub const FILM_BYTES_PER_PIXEL: u64 = 128;

/// Film size and reconstruction filter (`hdrfilm`).
#[derive(Clone, Debug)]
pub struct FilmSpec {
    pub width: usize,
    pub height: usize,
    pub rfilter: ReconstructionFilter,
}

impl FilmSpec {
    /// Reads `<film type="hdrfilm">`; Mitsuba's defaults are 768 × 576 with a Gaussian filter.
    pub fn from_props(props: &Props) -> Result<FilmSpec, SceneError> {
        if props.plugin_type != "hdrfilm" {
            return Err(
                props.error(format!("unsupported film type '{}' (supported: hdrfilm)", props.plugin_type))
            );
        }
        props.expect_only(
            &[
                "width",
                "height",
                "file_format",
                "pixel_format",
                "component_format",
                "banner",
                "high_quality_edges",
            ],
            &["rfilter"],
        )?;
        let width = props.int("width", 768)?;
        let height = props.int("height", 576)?;
        if !(1..=65536).contains(&width) || !(1..=65536).contains(&height) {
            return Err(props.error(format!("film size {width}x{height} is outside 1..65536")));
        }
        let film_bytes = (width * height) as u64 * FILM_BYTES_PER_PIXEL;
        crate::resources::check_fits(film_bytes, &format!("a {width}x{height} film"))
            .map_err(|e| props.error(e))?;
        let rfilter = match props.objects_with_tag("rfilter").next() {
            Some(f) => ReconstructionFilter::from_props(f)?,
            None => ReconstructionFilter::Gaussian { stddev: 0.5 },
        };
        Ok(FilmSpec { width: width as usize, height: height as usize, rfilter })
    }
}

impl Default for FilmSpec {
    fn default() -> Self {
        FilmSpec { width: 768, height: 576, rfilter: ReconstructionFilter::Gaussian { stddev: 0.5 } }
    }
}
