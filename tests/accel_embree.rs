//! Embree backend against hand-computable scenes: hit distances, barycentrics and ids, interval
//! bounds, packet/single agreement, watertightness on shared edges and vertices, and error handling.

use hslt::accel::embree::{embree_version, EmbreeScene, PacketHint};
use hslt::accel::{build, AccelKind, Hit, RayQuery};
use hslt::geometry::{Ray, TriangleMesh, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

fn mesh(name: &str, positions: &[[f32; 3]], indices: &[[u32; 3]]) -> TriangleMesh {
    TriangleMesh {
        name: name.to_string(),
        positions: positions.iter().map(|&p| Vec3::from(p)).collect(),
        indices: indices.to_vec(),
        ..Default::default()
    }
}

/// Right triangle in the plane z = 2 with p0 at the origin's projection, so (u, v) = (x, y).
fn triangle_at_z2() -> TriangleMesh {
    mesh("tri", &[[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]], &[[0, 1, 2]])
}

/// Axis-aligned cube [lo, hi]^3, 8 shared vertices, 12 outward-wound triangles.
fn cube(name: &str, lo: f32, hi: f32) -> TriangleMesh {
    let mut positions = Vec::new();
    for i in 0..8u32 {
        positions.push([
            if i & 1 != 0 { hi } else { lo },
            if i & 2 != 0 { hi } else { lo },
            if i & 4 != 0 { hi } else { lo },
        ]);
    }
    let quads = [
        [0, 2, 3, 1], // z = lo
        [4, 5, 7, 6], // z = hi
        [0, 1, 5, 4], // y = lo
        [2, 6, 7, 3], // y = hi
        [0, 4, 6, 2], // x = lo
        [1, 3, 7, 5], // x = hi
    ];
    let mut indices = Vec::new();
    for [a, b, c, d] in quads {
        indices.push([a, b, c]);
        indices.push([a, c, d]);
    }
    mesh(name, &positions, &indices)
}

fn ray(origin: Vec3, dir: Vec3) -> Ray {
    Ray::new(origin, dir)
}

fn hit_point(m: &TriangleMesh, hit: &Hit) -> Vec3 {
    let [p0, p1, p2] = m.vertices(hit.prim_id as usize);
    (1.0 - hit.u - hit.v) * p0 + hit.u * p1 + hit.v * p2
}

#[test]
fn single_triangle_distance_barycentrics_and_ids() {
    let tri = triangle_at_z2();
    let scene = EmbreeScene::build(std::slice::from_ref(&tri)).unwrap();
    let hit = scene
        .intersect(&ray(Vec3::new(0.2, 0.3, 5.0), Vec3::new(0.0, 0.0, -1.0)))
        .expect("ray through the interior must hit");
    assert_eq!((hit.geom_id, hit.prim_id), (0, 0));
    assert!((hit.t - 3.0).abs() < 1e-6, "t = {}", hit.t);
    assert!((hit.u - 0.2).abs() < 1e-6 && (hit.v - 0.3).abs() < 1e-6, "{hit:?}");

    // Oblique rays towards known barycentric points: Embree's (u, v) must reproduce the point with
    // p = (1-u-v) p0 + u p1 + v p2, and t must be the distance along the unnormalised direction.
    let mut rng = Pcg32::seed_from_u64(7);
    for _ in 0..200 {
        let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let target = Vec3::new(u, v, 2.0);
        let origin =
            Vec3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(-4.0..-1.0));
        let scale = rng.random_range(0.5f32..4.0);
        let dir = (target - origin) / scale;
        let hit = scene.intersect(&ray(origin, dir)).expect("aimed at the interior");
        assert!((hit.t - scale).abs() < 1e-4 * scale, "t {} vs {scale}", hit.t);
        assert!((hit.u - u).abs() < 1e-4 && (hit.v - v).abs() < 1e-4, "{hit:?} vs ({u}, {v})");
        assert!((hit_point(&tri, &hit) - target).length() < 1e-4);
    }

    // Misses: beside the triangle, pointing away, parallel to its plane.
    for (o, d) in [
        ([0.8, 0.8, 5.0], [0.0, 0.0, -1.0]),
        ([0.2, 0.2, 5.0], [0.0, 0.0, 1.0]),
        ([-1.0, 0.2, 2.0], [1.0, 0.0, 0.0]),
    ] {
        let r = ray(Vec3::from(o), Vec3::from(d));
        assert_eq!(scene.intersect(&r), None, "{r:?}");
        assert!(!scene.occluded(&r), "{r:?}");
    }
}

#[test]
fn unit_cube_faces_from_outside_and_inside() {
    let cube = cube("cube", 0.0, 1.0);
    let scene = EmbreeScene::build(std::slice::from_ref(&cube)).unwrap();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut dir = Vec3::ZERO;
            dir[axis] = -sign;
            let mut origin = Vec3::splat(0.375);
            origin[axis] = 0.5 + sign * 2.5; // 2 units outside the face it faces
            let hit = scene.intersect(&ray(origin, dir)).unwrap();
            assert!((hit.t - 2.0).abs() < 1e-6, "axis {axis} sign {sign}: {hit:?}");
            let n = cube.geometric_normal(hit.prim_id as usize);
            // Outward normal of the face entered first points back at the origin.
            assert!((n[axis] - sign).abs() < 1e-6, "axis {axis} sign {sign}: normal {n}");
            let p = hit_point(&cube, &hit);
            assert!((p - ray(origin, dir).at(hit.t)).length() < 1e-5);

            // From the inside, the same face is 0.5 - 0.375 + ... away along +dir reversed.
            let inside = ray(Vec3::splat(0.375), -dir);
            let hit = scene.intersect(&inside).unwrap();
            let expected = if sign > 0.0 { 0.625 } else { 0.375 };
            assert!((hit.t - expected).abs() < 1e-6, "{hit:?} expected {expected}");
        }
    }
}

#[test]
fn hits_outside_the_ray_interval_are_ignored() {
    let tri = triangle_at_z2();
    let scene = EmbreeScene::build(std::slice::from_ref(&tri)).unwrap();
    // The surface is at t = 1. Embree's t is accurate to a few ulps only, so the bounds are probed
    // 1e-5 away from it rather than exactly at it.
    let o = Vec3::new(0.25, 0.25, 3.0);
    let d = Vec3::new(0.0, 0.0, -1.0);
    let cases = [
        (0.0, 0.5, false),
        (0.0, 1.0 - 1e-5, false),
        (0.0, 1.0 + 1e-5, true),
        (0.0, f32::INFINITY, true),
        (1.0 - 1e-5, 2.0, true),
        (1.0 + 1e-5, 2.0, false),
        (-5.0, 0.5, false),
    ];
    for (tmin, tmax, expected) in cases {
        let r = Ray { origin: o, dir: d, tmin, tmax };
        assert_eq!(scene.occluded(&r), expected, "occluded {tmin}..{tmax}");
        assert_eq!(scene.intersect(&r).is_some(), expected, "intersect {tmin}..{tmax}");
        let mut occ = [!expected];
        scene.occluded_batch(&[r], &mut occ);
        assert_eq!(occ[0], expected, "occluded_batch {tmin}..{tmax}");
        let mut hits = [None];
        scene.intersect_batch(&[r], &mut hits);
        assert_eq!(hits[0].is_some(), expected, "intersect_batch {tmin}..{tmax}");
    }
}

/// Random triangle soup plus two cubes, with rays that start inside and outside, finite and infinite tmax.
fn random_scene_and_rays(seed: u64, ray_count: usize) -> (Vec<TriangleMesh>, Vec<Ray>) {
    let mut rng = Pcg32::seed_from_u64(seed);
    let mut soup = TriangleMesh { name: "soup".into(), ..Default::default() };
    for i in 0..600u32 {
        let c =
            Vec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
        for _ in 0..3 {
            soup.positions.push(
                c + Vec3::new(
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                ),
            );
        }
        soup.indices.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let meshes = vec![cube("a", -0.5, 0.5), soup, cube("b", 1.0, 2.0)];
    let rays = (0..ray_count)
        .map(|_| {
            let origin = Vec3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
            );
            let dir = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let tmax = if rng.random_bool(0.5) { f32::INFINITY } else { rng.random_range(0.1..6.0) };
            Ray { origin, dir, tmin: rng.random_range(0.0..0.05), tmax }
        })
        .collect();
    (meshes, rays)
}

fn same_hit(a: &Option<Hit>, b: &Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.geom_id == b.geom_id
                && a.prim_id == b.prim_id
                && (a.t - b.t).abs() <= 1e-5 * a.t.abs().max(1.0)
                && (a.u - b.u).abs() <= 1e-4
                && (a.v - b.v).abs() <= 1e-4
        }
        _ => false,
    }
}

#[test]
fn batches_agree_with_single_rays_for_every_batch_size() {
    let (meshes, mut rays) = random_scene_and_rays(11, 4000);
    // Invalid rays scattered through the packets must come back as misses without disturbing neighbours.
    for i in (5..rays.len()).step_by(97) {
        rays[i].origin.x = f32::NAN;
    }
    for i in (13..rays.len()).step_by(131) {
        rays[i].dir = Vec3::ZERO;
    }
    let scene = EmbreeScene::build(&meshes).unwrap();
    eprintln!("Embree {} packet width {}", embree_version(), scene.packet_width());
    let single_hits: Vec<Option<Hit>> = rays.iter().map(|r| scene.intersect(r)).collect();
    let single_occ: Vec<bool> = rays.iter().map(|r| scene.occluded(r)).collect();
    let hit_count = single_hits.iter().filter(|h| h.is_some()).count();
    assert!(
        hit_count > rays.len() / 5 && hit_count < rays.len() * 9 / 10,
        "test scene should give a mix of hits and misses, got {hit_count}"
    );
    for (h, o) in single_hits.iter().zip(&single_occ) {
        assert_eq!(h.is_some(), *o, "occluded must agree with intersect");
    }

    for batch in [1usize, 3, 17, 1000, rays.len()] {
        let mut hits = vec![None; rays.len()];
        let mut occ = vec![false; rays.len()];
        for ((r, h), o) in rays.chunks(batch).zip(hits.chunks_mut(batch)).zip(occ.chunks_mut(batch)) {
            scene.intersect_batch(r, h);
            scene.occluded_batch(r, o);
        }
        for i in 0..rays.len() {
            assert!(
                same_hit(&hits[i], &single_hits[i]),
                "batch {batch}, ray {i} {:?}: batch {:?} vs single {:?}",
                rays[i],
                hits[i],
                single_hits[i]
            );
            assert_eq!(occ[i], single_occ[i], "batch {batch}, ray {i}");
        }
    }
    scene.check_error().unwrap();
}

/// Bundles from one origin take Embree's coherent (frustum) packet traversal, a different code path
/// from the hybrid one the random rays above exercise. Bundles mix narrow cones, directions in every
/// octant, finite and infinite tmax, and an invalid ray, and every hint and the stream call must
/// agree with single rays.
#[test]
fn shared_origin_bundles_agree_with_single_rays_for_every_hint() {
    let (meshes, _) = random_scene_and_rays(5, 0);
    let scene = EmbreeScene::build(&meshes).unwrap();
    let mut rng = Pcg32::seed_from_u64(23);
    let mut rays = Vec::new();
    for bundle in 0..200 {
        let origin =
            Vec3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
        let axis =
            Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        // Odd bundles spread over all directions, so one packet straddles octants.
        let spread = if bundle % 2 == 0 { 0.03 } else { 1.0 };
        for k in 0..16 {
            let jitter = Vec3::new(
                rng.random_range(-spread..spread),
                rng.random_range(-spread..spread),
                rng.random_range(-spread..spread),
            );
            let tmax = if k % 3 == 0 { rng.random_range(0.5..4.0) } else { f32::INFINITY };
            let mut ray = Ray { origin, dir: axis + jitter, tmin: 0.0, tmax };
            if bundle % 7 == 0 && k == 5 {
                ray.dir = Vec3::ZERO;
            }
            rays.push(ray);
        }
    }
    let single_hits: Vec<Option<Hit>> = rays.iter().map(|r| scene.intersect(r)).collect();
    let single_occ: Vec<bool> = rays.iter().map(|r| scene.occluded(r)).collect();
    let hit_count = single_hits.iter().filter(|h| h.is_some()).count();
    assert!(hit_count > rays.len() / 5 && hit_count < rays.len() * 9 / 10, "{hit_count} hits");

    let check = |what: &str, hits: &[Option<Hit>], occ: &[bool]| {
        for i in 0..rays.len() {
            assert!(
                same_hit(&hits[i], &single_hits[i]),
                "{what}, ray {i} {:?}: {:?} vs single {:?}",
                rays[i],
                hits[i],
                single_hits[i]
            );
            assert_eq!(occ[i], single_occ[i], "{what}, ray {i} {:?}", rays[i]);
        }
    };
    for hint in [PacketHint::Incoherent, PacketHint::Coherent, PacketHint::SharedOrigin] {
        let mut hits = vec![None; rays.len()];
        let mut occ = vec![false; rays.len()];
        for ((r, h), o) in rays.chunks(16).zip(hits.chunks_mut(16)).zip(occ.chunks_mut(16)) {
            scene.intersect_packets(r, h, hint);
            scene.occluded_packets(r, o, hint);
        }
        check(&format!("{hint:?}"), &hits, &occ);
    }
    for coherent in [false, true] {
        let mut hits = vec![None; rays.len()];
        let mut occ = vec![false; rays.len()];
        scene.intersect_stream(&rays, &mut hits, coherent);
        scene.occluded_stream(&rays, &mut occ, coherent);
        check(&format!("stream, coherent {coherent}"), &hits, &occ);
    }
    scene.check_error().unwrap();
}

#[test]
fn geom_id_is_the_mesh_index_even_with_empty_meshes() {
    let far_tri = mesh("far", &[[0.0, 0.0, 10.0], [1.0, 0.0, 10.0], [0.0, 1.0, 10.0]], &[[0, 1, 2]]);
    let empty = TriangleMesh { name: "empty".into(), ..Default::default() };
    let meshes = vec![triangle_at_z2(), empty.clone(), far_tri, mesh("vertices only", &[[0.0; 3]], &[])];
    let scene = EmbreeScene::build(&meshes).unwrap();
    assert_eq!(scene.mesh_count(), 4);
    let up = Vec3::new(0.0, 0.0, 1.0);
    let near = scene.intersect(&ray(Vec3::new(0.1, 0.1, 0.0), up)).unwrap();
    assert_eq!((near.geom_id, near.prim_id), (0, 0));
    let past_near = Ray { tmin: 3.0, ..ray(Vec3::new(0.1, 0.1, 0.0), up) };
    let far = scene.intersect(&past_near).unwrap();
    assert_eq!(far.geom_id, 2);
    assert!((far.t - 10.0).abs() < 1e-5);

    // The empty-scene case: builds, everything misses.
    let nothing = EmbreeScene::build(&[empty]).unwrap();
    assert_eq!(nothing.intersect(&ray(Vec3::ZERO, up)), None);
    let no_meshes = EmbreeScene::build::<TriangleMesh>(&[]).unwrap();
    assert!(!no_meshes.occluded(&ray(Vec3::ZERO, up)));
}

/// Fan of 8 triangles sharing the apex (0, 0, 0.5) over the square rim with corners/midpoints at
/// (±1, ±1, 0): neighbouring triangles are not coplanar, and every point `apex + s (rim - apex)`
/// with dyadic `s` is exactly representable, so the rays below aim exactly at shared edges.
fn fan() -> (TriangleMesh, Vec<Vec3>) {
    let rim: [[f32; 3]; 8] = [
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [-1.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [1.0, -1.0, 0.0],
    ];
    let mut positions = vec![[0.0, 0.0, 0.5]];
    positions.extend_from_slice(&rim);
    let indices: Vec<[u32; 3]> = (0..8u32).map(|k| [0, 1 + k, 1 + (k + 1) % 8]).collect();
    let apex = Vec3::new(0.0, 0.0, 0.5);
    let mut targets = vec![apex];
    for r in rim {
        let r = Vec3::from(r);
        for s in [0.125f32, 0.25, 0.5, 0.75, 0.875] {
            targets.push(apex + s * (r - apex));
        }
    }
    (mesh("fan", &positions, &indices), targets)
}

/// Interior of the solid bounded by the fan (z = 0.5 (1 - max(|x|, |y|))) and the plane z = 0, with a
/// margin so that points on the surface do not count.
fn inside_fan_pyramid(p: Vec3) -> bool {
    let margin = 1e-3;
    let m = p.x.abs().max(p.y.abs());
    m < 1.0 - margin && p.z > margin && p.z < 0.5 * (1.0 - m) - margin
}

#[test]
fn rays_aimed_at_shared_edges_and_vertices_never_slip_through_in_robust_mode() {
    let (fan, targets) = fan();
    let scene = EmbreeScene::build_robust(std::slice::from_ref(&fan)).unwrap();
    let mut rng = Pcg32::seed_from_u64(3);
    let mut rays = Vec::new();
    let mut candidates = 0;
    for &target in &targets {
        for _ in 0..60 {
            // From above and below, at all azimuths.
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let origin = Vec3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                side * rng.random_range(1.0..4.0),
            );
            let r = ray(origin, target - origin);
            candidates += 1;
            // Keep rays that really cross the surface there: just before or just after the aimed-at
            // point they are inside the pyramid. A ray that only touches the convex ridge and stays
            // outside may legitimately miss, so it says nothing about watertightness.
            if inside_fan_pyramid(r.at(0.99)) || inside_fan_pyramid(r.at(1.01)) {
                rays.push(r);
            }
        }
    }
    assert!(rays.len() > candidates / 3, "only {} crossing rays", rays.len());
    let mut slipped = Vec::new();
    for r in &rays {
        match scene.intersect(r) {
            // Another part of the fan may be in front of the aimed-at point, never behind it.
            Some(hit) => assert!(hit.t < 1.0 + 1e-4, "{r:?} hit at {hit:?}"),
            None => slipped.push(*r),
        }
    }
    assert!(
        slipped.is_empty(),
        "{} of {} rays slipped through, e.g. {:?} aimed at {}",
        slipped.len(),
        rays.len(),
        slipped[0],
        slipped[0].at(1.0)
    );

    let mut occ = vec![false; rays.len()];
    scene.occluded_batch(&rays, &mut occ);
    assert!(occ.iter().all(|&o| o), "a packet ray slipped through");

    // The default mode (Mitsuba 3's flags) is not watertight, but rays aimed exactly at an edge are
    // the only ones it can lose, and it loses few of them.
    let fast = EmbreeScene::build(std::slice::from_ref(&fan)).unwrap();
    let lost = rays.iter().filter(|r| fast.intersect(r).is_none()).count();
    assert!(lost * 100 <= rays.len(), "the default mode lost {lost} of {} edge rays", rays.len());

    // Cube corners and edge midpoints, approached from outside so the ray continues into the solid.
    let cube = cube("cube", -1.0, 1.0);
    let scene = EmbreeScene::build(std::slice::from_ref(&cube)).unwrap();
    let mut cube_rays = Vec::new();
    for corner in 0..8 {
        let c = Vec3::new(
            if corner & 1 != 0 { 1.0 } else { -1.0 },
            if corner & 2 != 0 { 1.0 } else { -1.0 },
            if corner & 4 != 0 { 1.0 } else { -1.0 },
        );
        for _ in 0..30 {
            let away = Vec3::new(
                c.x * rng.random_range(0.1..2.0),
                c.y * rng.random_range(0.1..2.0),
                c.z * rng.random_range(0.1..2.0),
            );
            cube_rays.push(ray(c + away, -away));
            // Midpoint of the edge along x through this corner: zero x component is exact.
            let edge = Vec3::new(0.0, c.y, c.z);
            let away = Vec3::new(rng.random_range(-0.5..0.5), away.y, away.z);
            cube_rays.push(ray(edge + away, -away));
        }
    }
    for r in &cube_rays {
        assert!(scene.intersect(r).is_some(), "slipped past the cube: {r:?}");
    }
}

#[test]
fn bad_meshes_are_errors_not_crashes() {
    let mut nan = triangle_at_z2();
    nan.name = "bunny".into();
    nan.positions[1].y = f32::NAN;
    let err = EmbreeScene::build(&[cube("ok", 0.0, 1.0), nan])
        .err()
        .expect("NaN vertex must be rejected")
        .to_string();
    assert!(
        err.contains("mesh #1 'bunny'") && err.contains("vertex 1") && err.contains("non-finite"),
        "{err}"
    );

    let mut inf = triangle_at_z2();
    inf.positions[2].z = f32::INFINITY;
    assert!(EmbreeScene::build(&[inf]).is_err());

    let mut out_of_range = cube("box", 0.0, 1.0);
    out_of_range.indices[5][2] = 8;
    let err = EmbreeScene::build(&[out_of_range])
        .err()
        .expect("index 8 of 8 vertices must be rejected")
        .to_string();
    assert!(err.contains("'box'") && err.contains("triangle 5") && err.contains("index 8"), "{err}");
}

#[test]
fn non_finite_rays_are_misses() {
    let scene = EmbreeScene::build(&[cube("cube", -1.0, 1.0)]).unwrap();
    let bad = [
        ray(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
        ray(Vec3::new(f32::INFINITY, 0.0, 0.0), -Vec3::X),
        ray(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 0.0)),
        ray(Vec3::ZERO, Vec3::new(0.0, f32::NEG_INFINITY, 0.0)),
        ray(Vec3::ZERO, Vec3::ZERO),
        Ray { tmin: f32::NAN, ..ray(Vec3::ZERO, Vec3::X) },
    ];
    for r in &bad {
        assert_eq!(scene.intersect(r), None, "{r:?}");
        assert!(!scene.occluded(r), "{r:?}");
    }
    let mut hits = vec![Some(Hit { t: 0.0, geom_id: 9, prim_id: 9, u: 0.0, v: 0.0 }); bad.len()];
    scene.intersect_batch(&bad, &mut hits);
    assert!(hits.iter().all(Option::is_none));
    let mut occ = vec![true; bad.len()];
    scene.occluded_batch(&bad, &mut occ);
    assert!(occ.iter().all(|&o| !o));
    scene.check_error().unwrap();
}

#[test]
fn trait_object_is_shareable_across_threads() {
    let (meshes, rays) = random_scene_and_rays(5, 2000);
    let accel: Box<dyn RayQuery> = build(AccelKind::Embree, &meshes).unwrap();
    assert_eq!(accel.name(), "embree");
    let expected: Vec<Option<Hit>> = rays.iter().map(|r| accel.intersect(r)).collect();
    let accel = &*accel;
    std::thread::scope(|s| {
        let handles: Vec<_> = rays
            .chunks(500)
            .map(|chunk| {
                s.spawn(move || {
                    hslt::accel::embree::set_flush_denormals();
                    let mut hits = vec![None; chunk.len()];
                    accel.intersect_batch(chunk, &mut hits);
                    hits
                })
            })
            .collect();
        let got: Vec<Option<Hit>> = handles.into_iter().flat_map(|h| h.join().unwrap()).collect();
        for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
            assert!(same_hit(g, e), "ray {i}: {g:?} vs {e:?}");
        }
    });
}

#[test]
fn runtime_version_and_packet_width_are_sane() {
    let version = embree_version();
    assert!(version.starts_with("3."), "{version}");
    let scene = EmbreeScene::build(&[triangle_at_z2()]).unwrap();
    assert!([1, 4, 8, 16].contains(&scene.packet_width()));
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && !std::arch::is_x86_feature_detected!("avx512f") {
        // Debian builds Embree with AVX2 kernels, so an AVX2 machine must get 8-wide packets.
        assert_eq!(scene.packet_width(), 8);
    }
}

/// The renderer's batch entry point (the trait method, which uses Embree's stream call) must give
/// exactly the single-ray answers.
#[test]
fn trait_batch_queries_match_single_rays() {
    use hslt::accel::{build, AccelKind, RayQuery};
    use hslt::geometry::{Ray, TriangleMesh, Vec3};
    use hslt::sampling::{square_to_uniform_sphere, Sampler};
    let mut mesh = TriangleMesh { name: "grid".into(), ..Default::default() };
    for i in 0..8 {
        for j in 0..8 {
            let (x, y) = (i as f32 - 4.0, j as f32 - 4.0);
            let base = mesh.positions.len() as u32;
            let z = 0.1 * ((i * 7 + j * 3) % 5) as f32;
            mesh.positions.extend([Vec3::new(x, y, z), Vec3::new(x + 1.0, y, z), Vec3::new(x, y + 1.0, -z)]);
            mesh.indices.push([base, base + 1, base + 2]);
        }
    }
    let accel: Box<dyn RayQuery> = build(AccelKind::Embree, &[mesh]).unwrap();
    let mut s = Sampler::new(5, 0, 0);
    let rays: Vec<Ray> = (0..1003)
        .map(|_| {
            let o = Vec3::new(s.next_1d() * 8.0 - 4.0, s.next_1d() * 8.0 - 4.0, 3.0);
            let mut d = square_to_uniform_sphere(s.next_2d());
            d.z = -d.z.abs();
            Ray::segment(o, d, 10.0 + s.next_1d() * 10.0)
        })
        .collect();
    let mut hits = vec![None; rays.len()];
    accel.intersect_batch(&rays, &mut hits);
    let mut blocked = vec![false; rays.len()];
    accel.occluded_batch(&rays, &mut blocked);
    let mut n_hits = 0;
    for (i, r) in rays.iter().enumerate() {
        assert_eq!(hits[i], accel.intersect(r), "ray {i}");
        assert_eq!(blocked[i], accel.occluded(r), "ray {i}");
        n_hits += hits[i].is_some() as usize;
    }
    assert!(n_hits > 100 && n_hits < rays.len(), "degenerate ray set: {n_hits} hits");
}
