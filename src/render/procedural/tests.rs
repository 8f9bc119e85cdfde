use glam::{Quat, Vec2, Vec3};

use super::props::*;
use super::shapes::*;
use super::view::*;
use super::*;
use crate::render::bvh::SceneBvh;
use crate::render::camera::{Camera, CameraPathSpec};
use crate::render::packed::straight_through;
use crate::render::scene::Geometry;

fn fingerprint(s: &Scene) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |v: u64| {
        h ^= v;
        h = h.wrapping_mul(0x0100_0000_01b3);
    };
    for p in &s.geometry.positions {
        for c in p.to_array() {
            eat(c.to_bits() as u64);
        }
    }
    for t in &s.geometry.triangles {
        eat(((t[0] as u64) << 32) ^ ((t[1] as u64) << 16) ^ t[2] as u64);
    }
    for &m in &s.geometry.materials {
        eat(m as u64);
    }
    for m in &s.materials {
        for c in
            m.base_color
                .iter()
                .chain(&m.emissive)
                .chain([&m.metallic, &m.roughness, &m.transmission, &m.ior])
        {
            eat(c.to_bits() as u64);
        }
        eat(m.base_color_texture.map_or(u64::MAX, |t| t as u64));
    }
    for t in &s.textures {
        for px in t.texels.iter().step_by(17) {
            eat(u32::from_le_bytes(*px) as u64);
        }
    }
    if let Some(e) = &s.environment {
        eat(e.scale.to_bits() as u64);
        for p in e.pixels.iter().step_by(97) {
            eat(p[0].to_bits() as u64);
        }
    }
    eat(s.camera.position.x.to_bits() as u64);
    eat(format!("{:?}", s.camera_path).len() as u64);
    h
}

fn no_props() -> PropLibrary {
    PropLibrary::default()
}

/// The environment's portals are the open windows and those with smooth panes: through
/// each, at least one of three points is open or behind such a pane or a cut-out grille
/// (objects placed against a wall may cover the rest), a rough pane is never met, and
/// the camera, in the room, is on its inner side.
#[test]
fn portals_are_open_windows() {
    let mut lib = no_props();
    let (mut with, mut portals, mut panes) = (0, 0, 0);
    for seed in 0..48u64 {
        let s = generate_with(seed, &mut lib).unwrap().scene;
        let Some(e) = &s.environment else { continue };
        if e.portals.is_empty() {
            continue;
        }
        with += 1;
        let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
        for q in &e.portals {
            portals += 1;
            let n = q.u.cross(q.v).normalize();
            let mut open = 0;
            for (a, b) in [(0.5, 0.5), (0.2, 0.3), (0.8, 0.7)] {
                let p = q.corner + a * q.u + b * q.v;
                let hit = bvh.intersect(p + 0.1 * n, -n, 0.2);
                let Some((tri, _)) = hit else {
                    open += 1;
                    continue;
                };
                let m = &s.materials[s.geometry.materials[bvh.order[tri as usize] as usize] as usize];
                let rough_pane = m.thin && m.transmission > 0.0 && !straight_through(m);
                assert!(!rough_pane, "seed {seed}: portal {q:?} behind a rough pane");
                if straight_through(m) {
                    panes += 1;
                    open += 1;
                } else if matches!(m.alpha, AlphaMode::Mask(_)) {
                    open += 1; // a grille: cut-outs let shadow rays through
                }
            }
            assert!(open > 0, "seed {seed}: portal {q:?} is blocked");
            assert!(
                (s.camera.position - q.corner).dot(n) > 0.0,
                "seed {seed}: portal {q:?} faces away from the camera in the room"
            );
        }
    }
    assert!(
        with >= 5 && portals >= with && panes > 0,
        "{with} scenes with {portals} portals, {panes} pane hits"
    );
}

#[test]
fn seeds_validate_light_and_see_geometry() {
    let mut enclosures = std::collections::BTreeSet::new();
    let mut kinds = std::collections::BTreeSet::new();
    let mut paths = std::collections::BTreeSet::new();
    let mut prints = std::collections::HashSet::new();
    let mut lib = no_props();
    for seed in 0..64u64 {
        let g = generate_with(seed, &mut lib).unwrap();
        let s = &g.scene;
        s.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert_eq!(s.name, format!("builtin:procedural:{seed}"));
        assert!(
            (5..=40).contains(&g.objects) || g.attempt == MAX_ATTEMPTS,
            "seed {seed}: {} objects",
            g.objects
        );
        // Light: an emitter used by a triangle, or an environment.
        let emitter = s
            .geometry
            .materials
            .iter()
            .any(|&m| s.materials[m as usize].emitted_luminance(&s.textures) > 0.0);
        assert!(emitter || s.environment.is_some(), "seed {seed}: no light");
        // Visible geometry from the camera, checked independently here.
        let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
        let (w, h) = s.film;
        let mut hit = 0;
        for j in 0..8 {
            for i in 0..8 {
                let px = Vec2::new(
                    (i as f32 + 0.5) * w as f32 / 8.0,
                    (j as f32 + 0.5) * h as f32 / 8.0,
                );
                let d = s.camera.ray_dir(px, w, h);
                hit += bvh.intersect(s.camera.position, d, f32::INFINITY).is_some() as u32;
            }
        }
        assert!(hit >= 16, "seed {seed}: only {hit} of 64 rays hit geometry");
        assert!(g.view.ok(), "seed {seed}: {:?}", g.view);
        // Exposure: the direct-light estimate of the image mean is never near-black.
        assert!(
            g.view.estimate >= 0.02 && g.view.estimate <= 2.0,
            "seed {seed}: estimate {} (gain {})",
            g.view.estimate,
            g.light_gain
        );
        enclosures.insert(g.enclosure);
        for (k, _) in material_kinds(s) {
            kinds.insert(k);
        }
        paths.insert(path_kind(&s.camera_path));
        assert!(
            prints.insert(fingerprint(s)),
            "seed {seed} repeats an earlier scene"
        );
    }
    assert_eq!(enclosures.len(), Enclosure::ALL.len(), "{enclosures:?}");
    assert_eq!(kinds.len(), MaterialKind::ALL.len(), "{kinds:?}");
    for p in ["static", "orbit", "flythrough", "keys", "cuts"] {
        assert!(paths.contains(p), "no {p} camera path in 64 seeds: {paths:?}");
    }
}

#[test]
fn same_seed_same_scene() {
    for seed in [0u64, 7, 12345, u64::MAX] {
        let a = procedural(seed, &SceneOptions::default()).unwrap();
        let b = procedural(seed, &SceneOptions::default()).unwrap();
        assert_eq!(a.geometry.triangles.len(), b.geometry.triangles.len());
        assert_eq!(fingerprint(&a), fingerprint(&b), "seed {seed}");
        assert_eq!(a.camera, b.camera);
        assert_eq!(a.camera_path, b.camera_path);
    }
    let a = fingerprint(&procedural(1, &SceneOptions::default()).unwrap());
    let b = fingerprint(&procedural(2, &SceneOptions::default()).unwrap());
    assert_ne!(a, b);
}

#[test]
fn seeds_parse_and_resolve() {
    assert_eq!(parse_seed("42").unwrap(), 42);
    assert_eq!(parse_seed("0xff").unwrap(), 255);
    assert_eq!(parse_seed(&u64::MAX.to_string()).unwrap(), u64::MAX);
    let e = parse_seed("seven").unwrap_err().to_string();
    assert!(e.contains("builtin:procedural:seven"), "{e}");
    let s = super::super::load::load_scene("builtin:procedural:3").unwrap();
    assert_eq!(s.name, "builtin:procedural:3");
    assert!(super::super::load::load_scene("builtin:procedural:").is_err());
    assert!(super::super::load::load_scene("builtin:procedural:-1").is_err());
}

#[test]
fn failed_attempts_retry_deterministically() {
    SABOTAGE.with(|s| s.set(3));
    let a = generate(5, &SceneOptions::default()).unwrap();
    let b = generate(5, &SceneOptions::default()).unwrap();
    SABOTAGE.with(|s| s.set(0));
    assert!(a.attempt >= 3, "attempt {}", a.attempt);
    assert!(a.view.ok() && a.view.has_light);
    assert_eq!(fingerprint(&a.scene), fingerprint(&b.scene));
    // Every attempt sabotaged: the fallback scene.
    SABOTAGE.with(|s| s.set(MAX_ATTEMPTS));
    let f = generate(5, &SceneOptions::default()).unwrap();
    SABOTAGE.with(|s| s.set(0));
    assert_eq!(f.attempt, MAX_ATTEMPTS);
    assert!(f.view.ok());
    f.scene.validate().unwrap();
}

#[test]
fn view_check_rejects_dark_and_empty_views() {
    let g = generate(11, &SceneOptions::default()).unwrap();
    let mut s = g.scene.clone();
    let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
    assert!(check_view(&s, &bvh, &s.camera, Some(g.object_triangles.clone())).ok());
    // Looking away from everything, from far outside.
    let away = Camera {
        position: Vec3::new(0.0, 500.0, 0.0),
        target: Vec3::new(0.0, 1000.0, 0.0),
        ..s.camera
    };
    let v = check_view(&s, &bvh, &away, None);
    assert!(!v.ok() && v.geometry == 0.0, "{v:?}");
    // No light at all.
    for m in &mut s.materials {
        m.emissive = [0.0; 3];
    }
    s.environment = None;
    let v = check_view(&s, &bvh, &s.camera, None);
    assert!(!v.ok() && !v.has_light && v.lit == 0.0, "{v:?}");
}

/// A glTF box (24 vertices, normals, uvs) with one material, as a data URI.
fn box_gltf() -> String {
    let mut g = Geometry::default();
    push_box(
        &mut g,
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.5, 1.0, 0.25),
        Quat::IDENTITY,
        1.0,
        0,
    );
    let mut bytes = Vec::new();
    for p in &g.positions {
        for c in p.to_array() {
            bytes.extend(c.to_le_bytes());
        }
    }
    let nb = bytes.len();
    for t in &g.triangles {
        for i in t {
            bytes.extend((*i as u16).to_le_bytes());
        }
    }
    let ib = bytes.len() - nb;
    let b64 = {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in bytes.chunks(3) {
            let n =
                (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
            for k in 0..4 {
                s.push(if k <= c.len() {
                    A[(n >> (18 - 6 * k) & 63) as usize] as char
                } else {
                    '='
                });
            }
        }
        s
    };
    format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0}}],
        "materials": [{{"name": "teal", "pbrMetallicRoughness": {{"baseColorFactor": [0.1, 0.6, 0.6, 1], "metallicFactor": 0, "roughnessFactor": 0.4}}}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1, "material": 0}}]}}],
        "accessors": [
          {{"bufferView": 0, "componentType": 5126, "count": {nv}, "type": "VEC3", "min": [-0.5, 0, -0.25], "max": [0.5, 2, 0.25]}},
          {{"bufferView": 1, "componentType": 5123, "count": {ni}, "type": "SCALAR"}}],
        "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": {nb}}}, {{"buffer": 0, "byteOffset": {nb}, "byteLength": {ib}}}],
        "buffers": [{{"byteLength": {total}, "uri": "data:application/octet-stream;base64,{b64}"}}]}}"#,
        nv = g.positions.len(),
        ni = g.triangles.len() * 3,
        total = bytes.len(),
    )
}

#[test]
fn broken_props_are_skipped_with_one_warning() {
    let d = crate::io::test_dir("props");
    let sub = d.join("nested");
    std::fs::create_dir_all(&sub).unwrap();
    std::fs::write(d.join("broken.gltf"), "{ this is not glTF").unwrap();
    std::fs::write(sub.join("good.gltf"), box_gltf()).unwrap();
    std::fs::write(d.join("notes.txt"), "ignored").unwrap();
    let opts = SceneOptions {
        props: vec![d.clone()],
    };
    let mut lib = PropLibrary::load(&opts.props).unwrap();
    assert_eq!(lib.files.len(), 1, "{:?}", lib.warnings);
    assert_eq!(lib.warnings.len(), 1, "{:?}", lib.warnings);
    assert!(lib.warnings[0].contains("broken.gltf"), "{:?}", lib.warnings);
    let mut used = 0;
    for seed in 0..12 {
        let g = generate_with(seed, &mut lib).unwrap();
        g.scene.validate().unwrap();
        assert!(g.view.ok());
        let named: Vec<_> = g.warnings.iter().filter(|w| w.contains("broken.gltf")).collect();
        assert_eq!(named.len(), 1, "seed {seed}: {:?}", g.warnings);
        used += g.props.len();
        if !g.props.is_empty() {
            assert!(g.scene.materials.iter().any(|m| m.name == "teal"));
            assert!(g.props.iter().all(|p| p.contains("good.gltf")));
        }
    }
    assert!(used > 0, "the good prop was never placed");
    // The same through the public entry point.
    let s = super::super::load::load_scene_with("builtin:procedural:4", &opts).unwrap();
    s.validate().unwrap();
    // A props path that does not exist is an error naming it.
    let e = generate(
        1,
        &SceneOptions {
            props: vec![d.join("missing-folder")],
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("missing-folder"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn mesh_generators_face_outwards_with_consistent_tangents() {
    let mut g = Geometry::default();
    let c = Vec3::new(1.0, 2.0, -3.0);
    push_sphere(&mut g, c, 0.7, 16, 8, 1.0, 0);
    push_box(
        &mut g,
        c,
        Vec3::new(0.3, 0.5, 0.2),
        Quat::from_rotation_y(0.4),
        1.0,
        0,
    );
    push_cylinder(&mut g, c - Vec3::Y * 0.5, 0.4, 1.0, 12, 1.0, 0);
    for (k, t) in g.triangles.iter().enumerate() {
        let [a, b, cc] = t.map(|i| g.positions[i as usize]);
        let n = (b - a).cross(cc - a);
        let mid = (a + b + cc) / 3.0;
        assert!(n.dot(mid - c) > 0.0, "triangle {k} faces inwards");
        for &i in t {
            let (nn, tt) = (g.normals[i as usize], g.tangents[i as usize]);
            assert!(nn.dot(n.normalize()) > 0.0 || n.length() < 1e-6, "normal of {k}");
            assert!(
                tt.truncate().dot(nn).abs() < 1e-3,
                "tangent not perpendicular at {k}"
            );
            assert!(tt.w == 1.0);
        }
    }
    // Box faces: the bitangent (n x t) runs towards decreasing v, like the builtin room.
    let mut g = Geometry::default();
    push_box(&mut g, Vec3::ZERO, Vec3::ONE, Quat::IDENTITY, 1.0, 0);
    for t in &g.triangles {
        let [i0, i1, i2] = t.map(|i| i as usize);
        let (p0, p1, p2) = (g.positions[i0], g.positions[i1], g.positions[i2]);
        let (u0, u1, u2) = (g.uvs[i0], g.uvs[i1], g.uvs[i2]);
        // dP/dv from the triangle.
        let (e1, e2) = (p1 - p0, p2 - p0);
        let (d1, d2) = (u1 - u0, u2 - u0);
        let r = 1.0 / (d1.x * d2.y - d2.x * d1.y);
        let dpdv = (e2 * d1.x - e1 * d2.x) * r;
        let b = g.normals[i0].cross(g.tangents[i0].truncate());
        assert!(b.dot(dpdv) < 0.0, "bitangent along +v");
    }
    // A wall with a hole leaves the hole open and covers the rest.
    let mut g = Geometry::default();
    push_wall(
        &mut g,
        Vec3::ZERO,
        Vec3::X,
        Vec3::Y,
        4.0,
        3.0,
        &[[1.0, 2.0, 1.0, 2.0]],
        1.0,
        0,
    );
    let area: f32 = g
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| g.positions[i as usize]);
            0.5 * (b - a).cross(c - a).length()
        })
        .sum();
    assert!((area - 11.0).abs() < 1e-4, "{area}");
    let bvh = SceneBvh::build("wall", &g.positions, &g.triangles).unwrap();
    assert!(
        bvh.intersect(Vec3::new(1.5, 1.5, 1.0), Vec3::NEG_Z, 5.0)
            .is_none()
    );
    assert!(
        bvh.intersect(Vec3::new(0.5, 1.5, 1.0), Vec3::NEG_Z, 5.0)
            .is_some()
    );
}

#[test]
fn explicit_cut_paths_jump_between_keys() {
    use super::super::camera::CameraPath;
    let mut found = false;
    for seed in 0..64u64 {
        let s = procedural(seed, &SceneOptions::default()).unwrap();
        let Some(
            spec @ CameraPathSpec::FlyThrough {
                cut_every: Some(n),
                keys: Some(keys),
                ..
            },
        ) = &s.camera_path
        else {
            continue;
        };
        found = true;
        let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
        let path = CameraPath::from_spec(spec, &s.camera, 0, 4 * n, &bvh);
        assert_eq!(path.camera(0).position, keys[0].position);
        assert!(path.is_cut(*n) && !path.is_cut(*n - 1) && !path.is_cut(0));
        assert!(path.camera(*n).position.distance(keys[1].position) < 1e-5);
        break;
    }
    assert!(found, "no seed of 0..64 has explicit cuts");
}

/// The kind of a camera path: static, orbit, flythrough, keys (explicit keys) or cuts.
fn path_kind(path: &Option<CameraPathSpec>) -> &'static str {
    match path {
        Some(CameraPathSpec::Static) => "static",
        Some(CameraPathSpec::Orbit { .. }) => "orbit",
        Some(CameraPathSpec::FlyThrough {
            cut_every: Some(_), ..
        }) => "cuts",
        Some(CameraPathSpec::FlyThrough { keys: Some(_), .. }) => "keys",
        Some(CameraPathSpec::FlyThrough { .. }) => "flythrough",
        None => "none",
    }
}

/// What a seed's scene is, in terms that survive last-bit differences of the platform's
/// maths library: enclosure, counts, material kinds, camera path kind.
fn summary(seed: u64) -> String {
    let g = generate(seed, &SceneOptions::default()).unwrap();
    let s = &g.scene;
    let path = path_kind(&s.camera_path);
    let kinds: Vec<String> = material_kinds(s)
        .iter()
        .map(|(k, n)| format!("{}{n}", k.name()))
        .collect();
    format!(
        "{seed}: {} attempt {} objects {} triangles {} vertices {} textures {} [{}] {path}",
        g.enclosure.name(),
        g.attempt,
        g.objects,
        s.geometry.triangles.len(),
        s.geometry.positions.len(),
        s.textures.len(),
        kinds.join(" "),
    )
}

/// The generator's output for given seeds is part of the datasets' definition (their splits
/// are seed ranges, re-created by the recipe on a new machine): a change to what a seed
/// generates must be deliberate. If it is, re-render the datasets and update this list with
/// the printed lines.
#[test]
fn seeds_keep_their_scenes_across_versions() {
    // Printed by `subpixel scene --scene builtin:procedural:SEED` of a build three sessions
    // older (the one that rendered most of the train split) as well.
    let golden = [
        "0: room attempt 0 objects 11 triangles 6568 vertices 3912 textures 15 [emitter2 cut-out2 solid glass3 metal2 textured5 glossy2 diffuse2] flythrough",
        "1: open ground attempt 0 objects 31 triangles 15526 vertices 9903 textures 35 [emitter1 cut-out4 thin glass2 solid glass1 metal6 textured13 glossy4 diffuse8] cuts",
        "2: corridor attempt 0 objects 12 triangles 4854 vertices 3403 textures 11 [emitter6 cut-out1 thin glass1 solid glass2 metal2 textured4 glossy4 diffuse4] keys",
        "3: steps attempt 0 objects 36 triangles 14354 vertices 9655 textures 40 [emitter6 cut-out2 thin glass1 solid glass8 metal5 textured14 glossy4 diffuse6] flythrough",
        "4: room attempt 0 objects 14 triangles 13104 vertices 7700 textures 5 [thin glass2 solid glass2 metal2 textured2 glossy5 diffuse5] flythrough",
        "5: open ground attempt 0 objects 22 triangles 7760 vertices 5178 textures 11 [emitter4 cut-out1 thin glass2 solid glass4 metal5 textured4 glossy4 diffuse3] flythrough",
        "6: corridor attempt 0 objects 15 triangles 10104 vertices 6162 textures 13 [emitter10 cut-out2 thin glass2 solid glass2 metal5 textured4 glossy2 diffuse4] flythrough",
        "7: steps attempt 0 objects 18 triangles 5940 vertices 4244 textures 24 [emitter4 cut-out2 solid glass1 metal1 textured8 glossy2 diffuse5] static",
    ];
    let now: Vec<String> = (0..8).map(summary).collect();
    assert_eq!(
        now.iter().map(String::as_str).collect::<Vec<_>>(),
        golden,
        "the generator's output changed; if deliberate, the new lines are:\n{}",
        now.join("\n")
    );
}
