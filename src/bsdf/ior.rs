//! Named indices of refraction: Mitsuba 3's dielectric table (`ior.h`, values from Hecht, "Optics",
//! at ~589 nm) and RGB complex indices for conductor presets. Mitsuba's RGB variants integrate the
//! spectral η and k curves (Palik et al. via pbrt/Luxpop) against the CIE matching functions; the RGB
//! triples here are that same reduction as tabulated in Tungsten (`ComplexIorData.hpp`).

use crate::props::{PropValue, Props, SceneError};
use crate::spectrum::Spectrum;
use glam::Vec3;

const DIELECTRIC_IORS: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.3330),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.5750),
    ("diamond", 2.419),
];

/// Looks up a dielectric by name (case-insensitive).
pub fn named_ior(name: &str) -> Option<f32> {
    let lower = name.to_ascii_lowercase();
    DIELECTRIC_IORS.iter().find(|(n, _)| *n == lower).map(|&(_, v)| v)
}

/// Reads an IOR parameter given as a number or a material name; `default` is a table name.
pub fn read_ior(props: &Props, name: &str, default: &str) -> Result<f32, SceneError> {
    let value = match props.get(name).map(|p| &p.value) {
        None => named_ior(default).expect("default IOR names are in the table"),
        Some(PropValue::Float(v)) => *v as f32,
        Some(PropValue::Int(v)) => *v as f32,
        Some(PropValue::String(s)) => named_ior(s).ok_or_else(|| {
            let names: Vec<&str> = DIELECTRIC_IORS.iter().map(|(n, _)| *n).collect();
            props.error_at(
                name,
                format!(
                    "unknown index of refraction '{s}' for '{name}' (a number or one of: {})",
                    names.join(", ")
                ),
            )
        })?,
        Some(other) => {
            return Err(props.error_at(
                name,
                format!("parameter '{name}' is a {}, expected a float or a material name", other.kind()),
            ))
        }
    };
    if !(value.is_finite() && value > 0.0) {
        return Err(props.error_at(name, format!("'{name}' must be a positive number, got {value}")));
    }
    Ok(value)
}

/// (name, η, k) in linear sRGB, digits as tabulated.
#[allow(clippy::excessive_precision)]
const CONDUCTORS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("Ag", [0.155_264_65, 0.116_723_3, 0.138_380_7], [4.828_343_3, 3.122_246, 2.146_950_4]),
    ("Al", [1.657_46, 0.880_369, 0.521_228_7], [9.223_869, 6.269_523, 4.837_001]),
    ("Au", [0.143_118_96, 0.374_957_04, 1.442_478_6], [3.983_160_4, 2.385_720_7, 1.603_215_3]),
    ("Cr", [4.369_683, 2.916_702_5, 1.654_700_5], [5.206_434, 4.231_364_5, 3.754_946_7]),
    ("Cu", [0.200_437_7, 0.924_033_4, 1.102_212], [3.912_948_5, 2.452_847_7, 2.142_188]),
    ("Cu_palik", [0.212_684, 0.919_988, 1.102_407_8], [3.921_562_6, 2.457_149, 2.136_653_4]),
    ("Hg", [2.398_931_5, 1.440_025_5, 0.909_551_2], [6.327_627, 4.371_941_4, 3.421_79]),
    ("Ir", [3.086_41, 2.082_193_8, 1.617_886_7], [5.592_151, 4.067_175_7, 3.267_261]),
    ("Li", [0.265_787_2, 0.195_610_2, 0.220_919_85], [3.540_174_2, 2.311_130_5, 1.668_593]),
    ("Mo", [4.483_701, 3.525_457_8, 2.776_077], [4.111_131, 3.420_871_7, 3.150_603]),
    ("Ni_palik", [2.367_275_4, 1.663_358_3, 1.467_055_4], [4.498_833, 3.050_164_4, 2.345_427_5]),
    ("Rh", [2.585_795_4, 1.860_186_6, 1.554_428], [6.782_293, 4.702_95, 3.976_089_2]),
    ("Ta", [2.062_584_6, 2.393_091_5, 2.628_068_4], [2.408_046_7, 1.741_370_6, 1.947_037_7]),
    ("TiN", [1.648_469_2, 1.150_448_3, 1.379_779_5], [3.368_459_7, 1.943_488_9, 1.102_012_3]),
    ("W", [4.370_703, 3.300_297_3, 2.998_266_6], [3.500_678, 2.604_865_3, 2.273_193]),
];

/// Complex index (η, k) of a named conductor preset; "none" is Mitsuba's ideal mirror (η 0, k 1).
pub fn conductor_preset(name: &str) -> Option<(Spectrum, Spectrum)> {
    if name == "none" {
        return Some((Vec3::ZERO, Vec3::ONE));
    }
    CONDUCTORS.iter().find(|(n, _, _)| *n == name).map(|(_, e, k)| (Vec3::from(*e), Vec3::from(*k)))
}

pub fn conductor_preset_names() -> Vec<&'static str> {
    std::iter::once("none").chain(CONDUCTORS.iter().map(|(n, _, _)| *n)).collect()
}
