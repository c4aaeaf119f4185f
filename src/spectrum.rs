//! RGB spectra. The renderer works in linear sRGB primaries, as Mitsuba's `*_rgb` variants do.

pub type Spectrum = glam::Vec3;

/// Luminance of a linear sRGB colour (Rec. 709 weights).
pub fn luminance(s: Spectrum) -> f32 {
    0.212671 * s.x + 0.715160 * s.y + 0.072169 * s.z
}

pub fn is_black(s: Spectrum) -> bool {
    s.x == 0.0 && s.y == 0.0 && s.z == 0.0
}

pub fn is_finite(s: Spectrum) -> bool {
    s.is_finite()
}
