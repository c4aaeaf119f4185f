//! The pure-Rust BVH backend against Embree on the bundled scenes (same hits, distances, occlusion),
//! watertightness on shared edges and vertices, and a whole render that must not change with the backend.

use hslt::accel::{build, AccelKind, BvhScene, EmbreeScene};
use hslt::geometry::{Ray, TriangleMesh, Vec3};
use hslt::registry::IntegratorKind;
use hslt::scene::{LoadOptions, Scene};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;
use std::path::Path;

fn scene_meshes(path: &str) -> (Vec<TriangleMesh>, Vec3, f32) {
    let scene = Scene::load(Path::new(path), &LoadOptions::default()).unwrap();
    let meshes = scene.shapes.iter().map(|s| (*s.mesh).clone()).collect();
    (meshes, scene.bounds.center(), scene.bounds.radius())
}

fn random_dir(rng: &mut Pcg32) -> Vec3 {
    loop {
        let d =
            Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        if d.length_squared() > 1e-4 && d.length_squared() <= 1.0 {
            return d;
        }
    }
}

fn relative_gap(a: f32, b: f32) -> f32 {
    (a - b).abs() / a.abs().max(b.abs()).max(1e-20)
}

#[test]
fn both_backends_agree_on_random_rays_over_the_bundled_scenes() {
    for path in ["scenes/cornell-box/scene.xml", "scenes/materials/scene.xml"] {
        let (meshes, center, radius) = scene_meshes(path);
        let embree = EmbreeScene::build(&meshes).unwrap();
        let bvh = BvhScene::build(&meshes).unwrap();
        let mut rng = Pcg32::seed_from_u64(17);
        let (mut hits, mut prim_ties) = (0, 0);
        for i in 0..20_000 {
            // Origins inside and around the scene; some finite segments for occlusion.
            let origin = center + random_dir(&mut rng) * radius * 0.9;
            let dir = random_dir(&mut rng);
            let tmax = if i % 3 == 0 { rng.random_range(0.1..3.0) * radius } else { f32::INFINITY };
            let ray = Ray { origin, dir, tmin: 0.0, tmax };
            let (e, b) = (embree.intersect(&ray), bvh.intersect(&ray));
            match (e, b) {
                (None, None) => {}
                (Some(e), Some(b)) => {
                    hits += 1;
                    // Relative to the larger of t and the origin's distance from zero: both backends
                    // round positions at the scene's scale, so very short hits carry absolute error.
                    let scale = e.t.max(ray.origin.length() / ray.dir.length());
                    assert!((e.t - b.t).abs() < 1e-5 * scale, "{path}: {ray:?}: t {} vs {}", e.t, b.t);
                    if (e.geom_id, e.prim_id) != (b.geom_id, b.prim_id) {
                        prim_ties += 1;
                    } else {
                        assert!(
                            (e.u - b.u).abs() < 1e-4 && (e.v - b.v).abs() < 1e-4,
                            "{path}: {e:?} vs {b:?}"
                        );
                    }
                }
                _ => panic!("{path}: {ray:?}: embree {e:?}, bvh {b:?}"),
            }
            // Occlusion: skip segments ending within rounding of a surface, where the open interval
            // makes the answer legitimately ambiguous.
            let near_end = e.is_some_and(|h| relative_gap(h.t, tmax) < 1e-5);
            if !near_end {
                assert_eq!(embree.occluded(&ray), bvh.occluded(&ray), "{path}: occlusion of {ray:?}");
            }
        }
        assert!(hits > 5_000, "{path}: only {hits} hits; the rays do not exercise the scene");
        assert!(prim_ties < hits / 100, "{path}: {prim_ties} of {hits} hits on different triangles");
    }
}

/// A z = 0 grid of `n`² quads split along alternating diagonals (so vertices have 4 or 8 triangles).
fn grid(n: usize) -> TriangleMesh {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            positions.push(Vec3::new(i as f32 / n as f32, j as f32 / n as f32, 0.0));
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut indices = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                indices.extend([[a, b, c], [a, c, d]]);
            } else {
                indices.extend([[a, b, d], [b, c, d]]);
            }
        }
    }
    TriangleMesh { name: "grid".into(), positions, indices, ..Default::default() }
}

/// A fan of triangles around a centre vertex in a tilted plane (not axis-aligned).
fn tilted_fan(sides: usize) -> TriangleMesh {
    let mut positions = vec![Vec3::new(0.3, -0.2, 1.0)];
    for k in 0..sides {
        let a = std::f32::consts::TAU * k as f32 / sides as f32;
        positions.push(Vec3::new(0.3 + a.cos(), -0.2 + a.sin(), 1.0 + 0.37 * a.cos() - 0.21 * a.sin()));
    }
    let indices = (0..sides).map(|k| [0, 1 + k as u32, 1 + ((k + 1) % sides) as u32]).collect();
    TriangleMesh { name: "fan".into(), positions, indices, ..Default::default() }
}

#[test]
fn rays_at_shared_edges_and_vertices_never_slip_through() {
    let mut rng = Pcg32::seed_from_u64(5);
    let n = 16;
    let grid_scene = BvhScene::build(&[grid(n)]).unwrap();
    let fan = tilted_fan(11);
    let fan_scene = BvhScene::build(std::slice::from_ref(&fan)).unwrap();
    let mut targets: Vec<(&BvhScene, Vec3)> = Vec::new();
    // Every interior grid vertex and the midpoint of every interior grid edge (both axes, diagonals).
    for j in 1..n {
        for i in 1..n {
            let p = Vec3::new(i as f32 / n as f32, j as f32 / n as f32, 0.0);
            targets.push((&grid_scene, p));
            targets.push((&grid_scene, p + Vec3::new(0.5 / n as f32, 0.0, 0.0)));
            targets.push((&grid_scene, p + Vec3::new(0.0, 0.5 / n as f32, 0.0)));
            targets.push((&grid_scene, p + Vec3::new(0.5 / n as f32, 0.5 / n as f32, 0.0)));
        }
    }
    // The fan's centre and points along each spoke (shared edges) at several fractions.
    targets.push((&fan_scene, fan.positions[0]));
    for k in 1..fan.positions.len() {
        for f in [0.1f32, 0.25, 0.5, 0.77, 0.9] {
            targets.push((&fan_scene, fan.positions[0].lerp(fan.positions[k], f)));
        }
    }
    let mut rays = 0;
    for (scene, target) in targets {
        for _ in 0..24 {
            // From both sides, at all sorts of angles, including axis-aligned ones.
            let mut origin = target + random_dir(&mut rng) * rng.random_range(0.5..4.0);
            if rng.random_bool(0.2) {
                origin = target + Vec3::new(0.0, 0.0, if rng.random_bool(0.5) { 2.0 } else { -2.0 });
            }
            let ray = Ray::new(origin, target - origin);
            assert!(
                scene.intersect(&ray).is_some(),
                "ray at shared edge/vertex {target} slipped through: {ray:?}"
            );
            assert!(scene.occluded(&Ray { tmax: 2.0, ..ray }));
            rays += 1;
        }
    }
    assert!(rays > 20_000);
}

#[test]
fn empty_meshes_keep_their_geometry_ids() {
    let quad = grid(1);
    let empty = TriangleMesh { name: "empty".into(), ..Default::default() };
    let bvh = build(AccelKind::Bvh, &[empty.clone(), quad, empty]).unwrap();
    assert_eq!(bvh.name(), "bvh");
    let hit = bvh.intersect(&Ray::new(Vec3::new(0.6, 0.7, 1.0), -Vec3::Z)).unwrap();
    assert_eq!((hit.geom_id, hit.t), (1, 1.0));
    let nothing = build(AccelKind::Bvh, &[TriangleMesh::default()]).unwrap();
    assert!(nothing.intersect(&Ray::new(Vec3::ZERO, Vec3::Z)).is_none());
}

#[test]
fn default_scene_renders_the_same_with_either_backend() {
    let load = |accel| {
        let defines = vec![("resx".to_string(), "48".to_string()), ("resy".to_string(), "48".to_string())];
        Scene::load(Path::new("scenes/cornell-box/scene.xml"), &LoadOptions { defines, accel }).unwrap()
    };
    let (a, _) = hslt::cli::render_scene(&load(AccelKind::Embree), IntegratorKind::Path, 8, 3);
    let (b, _) = hslt::cli::render_scene(&load(AccelKind::Bvh), IntegratorKind::Path, 8, 3);
    assert_eq!(a.data.len(), b.data.len());
    // Same seed, same sample streams: the images differ only where a hit distance rounds differently
    // (a few ulps), or a path's Russian-roulette decision flips on such a rounding; both are rare.
    let total: f64 = a.data.iter().map(|&x| f64::from(x).abs()).sum();
    let diff: f64 = a.data.iter().zip(&b.data).map(|(&x, &y)| f64::from(x - y).abs()).sum();
    let close =
        a.data.iter().zip(&b.data).filter(|(&x, &y)| (x - y).abs() <= 1e-4 * x.abs().max(1e-3)).count();
    assert!(total > 0.0);
    eprintln!(
        "mean relative difference {:.3e}, {close} of {} values within 1e-4",
        diff / total,
        a.data.len()
    );
    assert!(diff / total < 1e-4, "mean relative difference {}", diff / total);
    assert!(close as f64 > 0.99 * a.data.len() as f64, "{close} of {} values agree", a.data.len());
}
