//! `hslt info`: what a scene contains and which parts of the renderer it needs.

use super::{load, SceneArgs};
use crate::accel::AccelKind;
use crate::scene::Scene;

pub(super) fn run_info(args: SceneArgs) -> anyhow::Result<i32> {
    let scene = load(&args, AccelKind::Embree)?;
    print!("{}", describe(&scene));
    Ok(0)
}

/// The `hslt info` report.
pub fn describe(scene: &Scene) -> String {
    use std::fmt::Write;
    let f = &scene.features;
    let mut s = String::new();
    let _ = writeln!(s, "scene      {}", scene.path.display());
    let _ = writeln!(s, "film       {} x {}, {:?}", scene.film.width, scene.film.height, scene.film.rfilter);
    let _ = writeln!(s, "samples    {} per pixel", scene.spp);
    let _ = writeln!(
        s,
        "integrator {} (max_depth {}, rr_depth {})",
        scene.integrator.kind, scene.integrator.max_depth, scene.integrator.rr_depth
    );
    let _ = writeln!(s, "shapes     {}", scene.shapes.len());
    let _ = writeln!(s, "triangles  {}", f.triangles);
    let _ = writeln!(s, "materials  {}", f.bsdf_types.join(", "));
    let _ = writeln!(s, "lights     {} ({})", scene.lights.len(), f.light_types.join(", "));
    let _ = writeln!(s, "textures   {} bitmap(s)", f.textures);
    let _ = writeln!(s, "bounds     {:?} .. {:?}", scene.bounds.min, scene.bounds.max);
    let yes = |b: bool| if b { "yes" } else { "no" };
    let _ = writeln!(s, "needs      texture system: {}", yes(f.textures > 0));
    let _ =
        writeln!(s, "           manifold walk (specular/glossy vertices): {}", yes(f.needs_manifold_walk()));
    let _ = writeln!(s, "           refraction: {}", yes(f.has_transmission));
    let _ = writeln!(s, "           environment lighting: {}", yes(!scene.infinite_lights.is_empty()));
    s
}
