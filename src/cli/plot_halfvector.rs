//! `hslt plot-halfvector`: the HSLT supplement's half-vector plots (Kaplanyan et al. 2014, supplement
//! Sec. 2–3, Fig. 4) for one path through a chosen pixel, drawn as three false-colour polar plots in one
//! image. The sweep itself is `manifold::sweep`; this module finds the path and draws.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;

use super::{check_output_paths, load, SceneArgs};
use crate::accel::AccelKind;
use crate::image::{srgb_to_linear, write_image, ImageBuf};
use crate::manifold::sweep::{find_path, grid_half_vector, HalfVectorSweep, PathSearch};

/// Arguments of `hslt plot-halfvector` (its help text is on `Command::PlotHalfvector`).
#[derive(Args, Debug)]
pub struct PlotHalfvectorArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Pixel the path passes through, as X,Y (column, row from the top-left).
    #[arg(long, value_name = "X,Y", value_parser = parse_pixel)]
    pub pixel: (u32, u32),
    /// Path index of the vertex to sweep (x_0 is the camera, so 1 is the first surface hit).
    #[arg(long, value_name = "I")]
    pub vertex: usize,
    /// Output PNG holding the three plots side by side.
    #[arg(short, long = "output")]
    pub output: PathBuf,
    /// Plot size in cells per side (each plot is RESOLUTION×RESOLUTION pixels).
    #[arg(long, default_value_t = 128)]
    pub resolution: usize,
    /// Seed of the camera samples that look for a path.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Longest path considered, in segments.
    #[arg(long, default_value_t = 6)]
    pub max_depth: usize,
    /// Camera samples tried before giving up.
    #[arg(long, default_value_t = 4096)]
    pub attempts: usize,
}

fn parse_pixel(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("'{s}' is not a pixel: expected X,Y with non-negative integers, e.g. 120,64");
    let (x, y) = s.split_once(',').ok_or_else(bad)?;
    Ok((x.trim().parse().map_err(|_| bad())?, y.trim().parse().map_err(|_| bad())?))
}

pub fn run(args: PlotHalfvectorArgs) -> anyhow::Result<i32> {
    if args.output.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref()
        != Some("png")
    {
        bail!("{}: plot-halfvector writes a PNG (expected a name ending in .png)", args.output.display());
    }
    check_output_paths(std::slice::from_ref(&args.output))?;
    if !(2..=4096).contains(&args.resolution) {
        bail!("--resolution must be between 2 and 4096 cells per side, got {}", args.resolution);
    }
    if args.max_depth < 2 {
        bail!("--max-depth must be at least 2 segments (a path with one inner vertex)");
    }
    let scene = load(&args.scene, AccelKind::Embree)?;
    let search = PathSearch {
        pixel: args.pixel,
        vertex: args.vertex,
        max_vertices: args.max_depth + 1,
        seed: args.seed,
        attempts: args.attempts.max(1),
    };
    let path = find_path(&scene, &search)?;
    let sweep = HalfVectorSweep::new(&scene, &path, args.vertex)?;
    let h = sweep.half_vectors()[args.vertex - 1];
    eprintln!(
        "path of {} vertices through pixel ({}, {}); vertex {} has h⊥ = ({:.4}, {:.4})",
        path.len(),
        args.pixel.0,
        args.pixel.1,
        args.vertex,
        h.x,
        h.y
    );
    let result = sweep.sweep(args.resolution);
    let (contribution, bsdf, difference) = result.normalised();
    let inside = (0..args.resolution * args.resolution)
        .filter(|&i| grid_half_vector(args.resolution, i % args.resolution, i / args.resolution).is_some())
        .count();
    let valid = result.valid.iter().filter(|&&v| v).count();
    let max_difference = difference.iter().copied().fold(0.0, f64::max);
    eprintln!(
        "{valid} of {inside} disk cells valid; largest normalised difference {max_difference:.3}{}",
        result
            .contribution_peak()
            .map_or(String::new(), |p| format!("; contribution peaks at h⊥ = ({:.3}, {:.3})", p.x, p.y))
    );
    let image = compose(args.resolution, &result.valid, &[&contribution, &bsdf, &difference]);
    let meta = vec![
        ("hslt.version".into(), env!("CARGO_PKG_VERSION").into()),
        ("hslt.scene".into(), scene.path.display().to_string()),
        ("hslt.plot".into(), "half-vector: contribution f_H, local BSDF, |difference|".into()),
        ("hslt.pixel".into(), format!("{},{}", args.pixel.0, args.pixel.1)),
        ("hslt.vertex".into(), args.vertex.to_string()),
        ("hslt.seed".into(), args.seed.to_string()),
    ];
    write_image(&args.output, &image, &meta)
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    eprintln!("wrote {}", args.output.display());
    Ok(0)
}

/// The panels side by side on a transparent background, `values` in [0, 1] per cell.
fn compose(resolution: usize, valid: &[bool], panels: &[&[f64]]) -> ImageBuf {
    let gap = (resolution / 16).max(2);
    let width = panels.len() * resolution + (panels.len() - 1) * gap;
    let mut image = ImageBuf::new(width, resolution, 4);
    for (p, values) in panels.iter().enumerate() {
        let x0 = p * (resolution + gap);
        for row in 0..resolution {
            for column in 0..resolution {
                if grid_half_vector(resolution, column, row).is_none() {
                    continue;
                }
                let cell = row * resolution + column;
                let rgb = if valid[cell] { viridis(values[cell]) } else { [0.0; 3] };
                let px = image.pixel_mut(x0 + column, row);
                // The colour map is defined in display (sRGB) values; the image buffer is linear.
                for c in 0..3 {
                    px[c] = srgb_to_linear(rgb[c] as f32);
                }
                px[3] = 1.0;
            }
        }
    }
    image
}

/// A polynomial fit of matplotlib's viridis (sRGB values), t clamped to [0, 1].
pub fn viridis(t: f64) -> [f64; 3] {
    const C: [[f64; 3]; 7] = [
        [0.277_727_327_223_417_7, 0.005_407_344_544_966_578, 0.334_099_805_335_306_1],
        [0.105_093_043_108_577_4, 1.404_613_529_898_575, 1.384_590_162_594_685],
        [-0.330_861_828_725_556_3, 0.214_847_559_468_213, 0.095_095_163_028_236_59],
        [-4.634_230_498_983_486, -5.799_100_973_351_585, -19.332_440_956_279_87],
        [6.228_269_936_347_081, 14.179_933_366_805_09, 56.690_552_600_681_05],
        [4.776_384_997_670_288, -13.745_145_377_746_01, -65.353_032_632_373_37],
        [-5.435_455_855_934_631, 4.645_852_612_178_535, 26.312_435_249_583_2],
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let mut rgb = [0.0; 3];
    for (c, out) in rgb.iter_mut().enumerate() {
        *out = C.iter().rev().fold(0.0, |acc, k| acc * t + k[c]).clamp(0.0, 1.0);
    }
    rgb
}
