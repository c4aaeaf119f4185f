//! Warps from [0,1)² to disks, hemispheres, spheres, cones and triangles, with their densities
//! (pbrt-v4 §A.5; Shirley-Chiu concentric mapping).

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

pub fn square_to_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Cosine-weighted hemisphere around +z.
pub fn square_to_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = square_to_uniform_disk_concentric(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) / PI
}

pub fn square_to_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

pub fn uniform_sphere_pdf() -> f32 {
    1.0 / (4.0 * PI)
}

/// Uniform direction inside a cone of half-angle `acos(cos_max)` around +z.
pub fn square_to_uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let cos_t = (1.0 - u.x) + u.x * cos_max;
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
}

pub fn uniform_cone_pdf(cos_max: f32) -> f32 {
    1.0 / (2.0 * PI * (1.0 - cos_max))
}

/// Uniform barycentrics (b1, b2) over a triangle; the point is (1-b1-b2) p0 + b1 p1 + b2 p2.
pub fn square_to_uniform_triangle(u: Vec2) -> Vec2 {
    // Heitz 2019 low-distortion mapping.
    let (b0, b1);
    if u.x < u.y {
        b0 = u.x / 2.0;
        b1 = u.y - b0;
    } else {
        b1 = u.y / 2.0;
        b0 = u.x - b1;
    }
    Vec2::new(b1, 1.0 - b0 - b1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warps_land_in_their_domains() {
        for i in 0..64 {
            for j in 0..64 {
                let u = Vec2::new((i as f32 + 0.5) / 64.0, (j as f32 + 0.5) / 64.0);
                assert!(square_to_uniform_disk_concentric(u).length() <= 1.0 + 1e-6);
                let h = square_to_cosine_hemisphere(u);
                assert!(h.z >= 0.0 && (h.length() - 1.0).abs() < 1e-4);
                assert!((square_to_uniform_sphere(u).length() - 1.0).abs() < 1e-4);
                let c = square_to_uniform_cone(u, 0.9);
                assert!(c.z >= 0.9 - 1e-6);
                let b = square_to_uniform_triangle(u);
                assert!(b.x >= 0.0 && b.y >= 0.0 && b.x + b.y <= 1.0 + 1e-6);
            }
        }
    }
}
