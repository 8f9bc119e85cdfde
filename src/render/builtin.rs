//! Built-in procedural scenes that need no files: `builtin:cornell` (the classic box with a
//! glass sphere and a metal block), `builtin:cornell-empty`, `builtin:room` (a textured room
//! lit by a sky through a window and a ceiling lamp) and `builtin:furnace` (a white
//! Lambertian sphere in a uniform white environment).

use glam::{Mat3, Quat, Vec2, Vec3, Vec4};

use super::camera::Camera;
use super::scene::{AlphaMode, Environment, Geometry, Material, Scene, Texture, Wrap};
use crate::error::{Error, Result};

/// Names accepted after `builtin:`.
pub const BUILTIN_SCENES: &[&str] = &["cornell", "cornell-empty", "room", "furnace"];

/// The built-in scene `name` (without the `builtin:` prefix).
pub fn builtin(name: &str) -> Result<Scene> {
    match name {
        "cornell" => Ok(cornell(&CornellOptions::default())),
        "cornell-empty" => Ok(cornell(&CornellOptions {
            objects: false,
            ..Default::default()
        })),
        "room" => Ok(room()),
        "furnace" => Ok(furnace()),
        _ => Err(Error::Scene {
            path: format!("builtin:{name}").into(),
            message: format!(
                "no such built-in scene (available: {})",
                BUILTIN_SCENES.join(", ")
            ),
        }),
    }
}

/// Variations of the Cornell box.
#[derive(Debug, Clone)]
pub struct CornellOptions {
    /// Add the glass sphere and the metal block.
    pub objects: bool,
    /// Left wall colour.
    pub left: [f32; 3],
    /// Right wall colour.
    pub right: [f32; 3],
    /// Floor, ceiling and back wall colour.
    pub white: [f32; 3],
    /// Light radiance.
    pub light: [f32; 3],
}

impl Default for CornellOptions {
    fn default() -> Self {
        Self {
            objects: true,
            left: [0.63, 0.065, 0.05],
            right: [0.14, 0.45, 0.091],
            white: [0.725, 0.71, 0.68],
            light: [17.0, 12.0, 4.0],
        }
    }
}

/// A UV sphere (smooth normals, uvs) centred at `c`.
pub fn push_sphere(g: &mut Geometry, c: Vec3, r: f32, segments: u32, rings: u32, material: u32) {
    let mut pos = Vec::new();
    let mut nrm = Vec::new();
    let mut uv = Vec::new();
    for j in 0..=rings {
        let v = j as f32 / rings as f32;
        let theta = v * std::f32::consts::PI;
        for i in 0..=segments {
            let u = i as f32 / segments as f32;
            let phi = u * std::f32::consts::TAU;
            let n = Vec3::new(theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin());
            pos.push(c + r * n);
            nrm.push(n);
            uv.push(Vec2::new(u, v));
        }
    }
    let mut tris = Vec::new();
    let row = segments + 1;
    for j in 0..rings {
        for i in 0..segments {
            let a = j * row + i;
            let b = a + row;
            // Counter-clockwise seen from outside.
            if j != 0 {
                tris.push([a, b, a + 1]);
            }
            if j != rings - 1 {
                tris.push([a + 1, b, b + 1]);
            }
        }
    }
    g.push_mesh(&pos, Some(&nrm), Some(&uv), None, &tris, material);
}

/// A box of half-extents `h`, rotated by `rot`, centred at `c` (faces outwards).
pub fn push_box(g: &mut Geometry, c: Vec3, h: Vec3, rot: Quat, material: u32) {
    let p = |x: f32, y: f32, z: f32| c + rot * (h * Vec3::new(x, y, z));
    let faces = [
        [p(-1., -1., 1.), p(1., -1., 1.), p(1., 1., 1.), p(-1., 1., 1.)],
        [p(1., -1., -1.), p(-1., -1., -1.), p(-1., 1., -1.), p(1., 1., -1.)],
        [p(1., -1., 1.), p(1., -1., -1.), p(1., 1., -1.), p(1., 1., 1.)],
        [p(-1., -1., -1.), p(-1., -1., 1.), p(-1., 1., 1.), p(-1., 1., -1.)],
        [p(-1., 1., 1.), p(1., 1., 1.), p(1., 1., -1.), p(-1., 1., -1.)],
        [p(-1., -1., -1.), p(1., -1., -1.), p(1., -1., 1.), p(-1., -1., 1.)],
    ];
    for [a, b, cc, d] in faces {
        g.push_quad(a, b, cc, d, material);
    }
}

fn add_material(s: &mut Scene, m: Material) -> u32 {
    s.materials.push(m);
    s.materials.len() as u32 - 1
}

fn empty_scene(name: &str, camera: Camera, film: (u32, u32)) -> Scene {
    Scene {
        name: name.into(),
        geometry: Geometry::default(),
        materials: Vec::new(),
        textures: Vec::new(),
        environment: None,
        camera,
        film,
        camera_path: None,
        approximations: Vec::new(),
    }
}

/// The Cornell box: a 2 x 2 x 2 room open towards the camera (+z), x in [-1, 1], y in
/// [0, 2], a ceiling light, and optionally a glass sphere and a metal block.
pub fn cornell(o: &CornellOptions) -> Scene {
    let camera = Camera {
        position: Vec3::new(0.0, 1.0, 3.94),
        target: Vec3::new(0.0, 1.0, 0.0),
        up: Vec3::Y,
        yfov: 39.3077f32.to_radians(),
    };
    let name = if o.objects {
        "builtin:cornell"
    } else {
        "builtin:cornell-empty"
    };
    let mut s = empty_scene(name, camera, (256, 256));
    let white = add_material(&mut s, Material::diffuse("white", o.white));
    let left = add_material(&mut s, Material::diffuse("left", o.left));
    let right = add_material(&mut s, Material::diffuse("right", o.right));
    let light = add_material(
        &mut s,
        Material {
            emissive: o.light,
            ..Material::diffuse("light", [0.78, 0.78, 0.78])
        },
    );
    let g = &mut s.geometry;
    let v = Vec3::new;
    g.push_quad(
        v(-1., 0., -1.),
        v(-1., 0., 1.),
        v(1., 0., 1.),
        v(1., 0., -1.),
        white,
    ); // floor
    g.push_quad(
        v(-1., 2., -1.),
        v(1., 2., -1.),
        v(1., 2., 1.),
        v(-1., 2., 1.),
        white,
    ); // ceiling
    g.push_quad(
        v(-1., 0., -1.),
        v(1., 0., -1.),
        v(1., 2., -1.),
        v(-1., 2., -1.),
        white,
    ); // back
    g.push_quad(
        v(-1., 0., -1.),
        v(-1., 2., -1.),
        v(-1., 2., 1.),
        v(-1., 0., 1.),
        left,
    );
    g.push_quad(
        v(1., 0., -1.),
        v(1., 0., 1.),
        v(1., 2., 1.),
        v(1., 2., -1.),
        right,
    );
    g.push_quad(
        v(-0.25, 1.98, -0.2),
        v(0.25, 1.98, -0.2),
        v(0.25, 1.98, 0.2),
        v(-0.25, 1.98, 0.2),
        light,
    );
    if o.objects {
        let glass = add_material(
            &mut s,
            Material {
                name: "glass".into(),
                metallic: 0.0,
                roughness: 0.0,
                transmission: 1.0,
                ior: 1.5,
                thin: false,
                ..Default::default()
            },
        );
        let metal = add_material(
            &mut s,
            Material {
                name: "metal".into(),
                base_color: [0.91, 0.92, 0.92, 1.0],
                metallic: 1.0,
                roughness: 0.25,
                ..Default::default()
            },
        );
        let g = &mut s.geometry;
        push_sphere(g, v(-0.42, 0.35, 0.3), 0.35, 48, 24, glass);
        push_box(
            g,
            v(0.38, 0.6, -0.35),
            v(0.28, 0.6, 0.28),
            Quat::from_rotation_y(0.35),
            metal,
        );
    }
    s
}

/// A white Lambertian sphere (no specular layer) of radius 1 in a uniform white
/// environment: every pixel converges to 1.
pub fn furnace() -> Scene {
    let camera = Camera {
        position: Vec3::new(0.0, 0.0, 4.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        yfov: 40f32.to_radians(),
    };
    let mut s = empty_scene("builtin:furnace", camera, (64, 64));
    let white = add_material(
        &mut s,
        Material {
            specular: 0.0,
            ..Material::diffuse("white", [1.0, 1.0, 1.0])
        },
    );
    push_sphere(&mut s.geometry, Vec3::ZERO, 1.0, 96, 48, white);
    s.environment = Some(Environment::uniform([1.0, 1.0, 1.0]));
    s
}

fn tex_from_fn(name: &str, w: u32, h: u32, srgb: bool, f: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
    let mut texels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            texels.push(f(x, y));
        }
    }
    Texture {
        name: name.into(),
        width: w,
        height: h,
        texels,
        srgb,
        wrap: [Wrap::Repeat; 2],
    }
}

fn add_texture(s: &mut Scene, t: Texture) -> u32 {
    s.textures.push(t);
    s.textures.len() as u32 - 1
}

fn hash2(x: u32, y: u32) -> f32 {
    let mut h = x.wrapping_mul(374761393) ^ y.wrapping_mul(668265263);
    h = (h ^ (h >> 13)).wrapping_mul(1274126177);
    ((h ^ (h >> 16)) & 0xffff) as f32 / 65535.0
}

/// A procedural sky: horizon-to-zenith gradient, dark ground, and a small bright sun.
fn sky() -> Environment {
    let (w, h) = (128u32, 64u32);
    let sun = Vec3::new(-0.35, 0.45, -0.82).normalize();
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let u = (x as f32 + 0.5) / w as f32;
            let v = (y as f32 + 0.5) / h as f32;
            let (theta, phi) = (v * std::f32::consts::PI, u * std::f32::consts::TAU);
            let d = Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos());
            let c = if d.y > 0.0 {
                let t = d.y.powf(0.5);
                Vec3::new(0.9, 0.95, 1.0).lerp(Vec3::new(0.25, 0.45, 0.95), t) * 1.5
            } else {
                Vec3::new(0.25, 0.22, 0.2)
            };
            let c = if d.dot(sun) > 0.995 {
                Vec3::new(400.0, 360.0, 300.0)
            } else {
                c
            };
            pixels.push(c.to_array());
        }
    }
    Environment {
        source: "procedural sky".into(),
        width: w,
        height: h,
        pixels,
        scale: 1.0,
        to_world: Mat3::IDENTITY,
    }
}

/// A 6 x 3 x 6 room with procedurally textured walls and floor (a normal-mapped brick wall
/// with a window to the sky), a ceiling lamp, a table, a metal sphere, a glass pane and a
/// cut-out (alpha-masked) leaf screen.
pub fn room() -> Scene {
    let camera = Camera {
        position: Vec3::new(1.2, 1.5, 2.6),
        target: Vec3::new(-0.3, 1.1, -1.5),
        up: Vec3::Y,
        yfov: 55f32.to_radians(),
    };
    let mut s = empty_scene("builtin:room", camera, (320, 240));
    // Textures.
    let checker = add_texture(
        &mut s,
        tex_from_fn("floor checker", 64, 64, true, |x, y| {
            let c = ((x / 8) + (y / 8)) % 2 == 0;
            let n = (hash2(x, y) * 20.0) as u8;
            if c {
                [150 + n, 110 + n, 70, 255]
            } else {
                [90 + n, 60 + n, 35, 255]
            }
        }),
    );
    let brick_colour = add_texture(
        &mut s,
        tex_from_fn("brick colour", 64, 64, true, |x, y| {
            let row = y / 8;
            let xo = (x + if row % 2 == 1 { 8 } else { 0 }) % 64;
            let mortar = y % 8 == 0 || xo % 16 == 0;
            if mortar {
                [200, 200, 195, 255]
            } else {
                let n = (hash2(xo / 16, row) * 40.0) as u8;
                [150 + n, 60 + n / 2, 45, 255]
            }
        }),
    );
    let brick_normal = add_texture(
        &mut s,
        tex_from_fn("brick normal", 64, 64, false, |x, y| {
            let row = y / 8;
            let xo = (x + if row % 2 == 1 { 8 } else { 0 }) % 64;
            // Grooves: tilt the normal towards the mortar lines.
            let nx = match xo % 16 {
                0 => 0.0,
                1 => -0.5,
                15 => 0.5,
                _ => 0.0,
            };
            let ny = match y % 8 {
                1 => 0.5,
                7 => -0.5,
                _ => 0.0,
            };
            let n = Vec3::new(nx, ny, 1.0).normalize();
            let e = |v: f32| ((v * 0.5 + 0.5) * 255.0).round() as u8;
            [e(n.x), e(n.y), e(n.z), 255]
        }),
    );
    let leaves = add_texture(
        &mut s,
        tex_from_fn("leaf cut-out", 64, 64, true, |x, y| {
            // Discs on a grid: opaque inside, transparent outside.
            let fx = (x % 16) as f32 - 7.5;
            let fy = (y % 16) as f32 - 7.5;
            let inside = fx * fx * 0.6 + fy * fy < 40.0;
            [60, 140, 50, if inside { 255 } else { 0 }]
        }),
    );
    let roughness_map = add_texture(
        &mut s,
        tex_from_fn("table metal-rough", 32, 32, false, |x, y| {
            let r = 120 + (hash2(x, y) * 100.0) as u8;
            [0, r, 0, 255]
        }),
    );
    let floor = add_material(
        &mut s,
        Material {
            base_color_texture: Some(checker),
            roughness: 0.6,
            ..Material::diffuse("floor", [1.0; 3])
        },
    );
    let bricks = add_material(
        &mut s,
        Material {
            base_color_texture: Some(brick_colour),
            normal_texture: Some(brick_normal),
            double_sided: true,
            ..Material::diffuse("bricks", [1.0; 3])
        },
    );
    let paint = add_material(&mut s, Material::diffuse("paint", [0.75, 0.72, 0.65]));
    let blue = add_material(&mut s, Material::diffuse("blue paint", [0.2, 0.3, 0.6]));
    let lamp = add_material(
        &mut s,
        Material {
            emissive: [25.0, 21.0, 15.0],
            ..Material::diffuse("lamp", [0.9; 3])
        },
    );
    let wood = add_material(
        &mut s,
        Material {
            metallic_roughness_texture: Some(roughness_map),
            roughness: 1.0,
            ..Material::diffuse("table", [0.45, 0.3, 0.18])
        },
    );
    let metal = add_material(
        &mut s,
        Material {
            name: "gold".into(),
            base_color: [0.97, 0.8, 0.32, 1.0],
            metallic: 1.0,
            roughness: 0.3,
            ..Default::default()
        },
    );
    let glass = add_material(
        &mut s,
        Material {
            name: "thin glass".into(),
            base_color: [0.85, 0.95, 0.9, 1.0],
            metallic: 0.0,
            roughness: 0.05,
            transmission: 1.0,
            thin: true,
            double_sided: true,
            ..Default::default()
        },
    );
    let leaf = add_material(
        &mut s,
        Material {
            base_color_texture: Some(leaves),
            alpha: AlphaMode::Mask(0.5),
            double_sided: true,
            ..Material::diffuse("leaves", [1.0; 3])
        },
    );
    let v = Vec3::new;
    let g = &mut s.geometry;
    let uvq = |g: &mut Geometry, q: [Vec3; 4], scale: Vec2, m: u32| {
        let uv = [
            Vec2::new(0.0, scale.y),
            Vec2::new(scale.x, scale.y),
            Vec2::new(scale.x, 0.0),
            Vec2::ZERO,
        ];
        let e1 = q[1] - q[0];
        let t = e1.normalize().extend(1.0);
        g.push_mesh(
            &q,
            None,
            Some(&uv),
            Some(&[t; 4] as &[Vec4]),
            &[[0, 1, 2], [0, 2, 3]],
            m,
        );
    };
    uvq(
        g,
        [v(-3., 0., 3.), v(3., 0., 3.), v(3., 0., -3.), v(-3., 0., -3.)],
        Vec2::splat(4.0),
        floor,
    );
    g.push_quad(
        v(-3., 3., -3.),
        v(3., 3., -3.),
        v(3., 3., 3.),
        v(-3., 3., 3.),
        paint,
    ); // ceiling
    // Back wall (z = -3) with a window x in [-1.5, 0.5], y in [1, 2.3].
    let back = |g: &mut Geometry, x0: f32, x1: f32, y0: f32, y1: f32| {
        let s = Vec2::new((x1 - x0) / 1.5, (y1 - y0) / 1.5);
        let q = [v(x0, y0, -3.), v(x1, y0, -3.), v(x1, y1, -3.), v(x0, y1, -3.)];
        let uv = [
            Vec2::new(x0 / 1.5, 2.0 - y0 / 1.5),
            Vec2::new(x0 / 1.5 + s.x, 2.0 - y0 / 1.5),
            Vec2::new(x0 / 1.5 + s.x, 2.0 - y0 / 1.5 - s.y),
            Vec2::new(x0 / 1.5, 2.0 - y0 / 1.5 - s.y),
        ];
        let t = Vec4::new(1.0, 0.0, 0.0, 1.0);
        g.push_mesh(
            &q,
            None,
            Some(&uv),
            Some(&[t; 4]),
            &[[0, 1, 2], [0, 2, 3]],
            bricks,
        );
    };
    back(g, -3.0, 3.0, 0.0, 1.0);
    back(g, -3.0, 3.0, 2.3, 3.0);
    back(g, -3.0, -1.5, 1.0, 2.3);
    back(g, 0.5, 3.0, 1.0, 2.3);
    g.push_quad(
        v(-3., 0., -3.),
        v(-3., 3., -3.),
        v(-3., 3., 3.),
        v(-3., 0., 3.),
        blue,
    ); // left
    g.push_quad(
        v(3., 0., 3.),
        v(3., 3., 3.),
        v(3., 3., -3.),
        v(3., 0., -3.),
        paint,
    ); // right
    g.push_quad(
        v(3., 0., 3.),
        v(-3., 0., 3.),
        v(-3., 3., 3.),
        v(3., 3., 3.),
        paint,
    ); // front
    g.push_quad(
        v(0.6, 2.98, -0.4),
        v(1.4, 2.98, -0.4),
        v(1.4, 2.98, 0.4),
        v(0.6, 2.98, 0.4),
        lamp,
    );
    // Table: top and four legs.
    push_box(g, v(0.0, 0.75, -1.2), v(0.8, 0.04, 0.5), Quat::IDENTITY, wood);
    for (lx, lz) in [(-0.7, -0.8), (0.7, -0.8), (-0.7, -1.6), (0.7, -1.6)] {
        push_box(g, v(lx, 0.355, lz), v(0.04, 0.355, 0.04), Quat::IDENTITY, wood);
    }
    push_sphere(g, v(0.3, 0.99, -1.2), 0.2, 32, 16, metal);
    // A thin glass pane in the window, slightly inside.
    g.push_quad(
        v(-1.5, 1.0, -2.95),
        v(0.5, 1.0, -2.95),
        v(0.5, 2.3, -2.95),
        v(-1.5, 2.3, -2.95),
        glass,
    );
    // A cut-out leaf screen standing on the floor.
    uvq(
        g,
        [
            v(-2.2, 0.0, -0.5),
            v(-1.2, 0.0, -1.0),
            v(-1.2, 1.6, -1.0),
            v(-2.2, 1.6, -0.5),
        ],
        Vec2::new(1.0, 1.5),
        leaf,
    );
    s.environment = Some(sky());
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_validate() {
        for name in BUILTIN_SCENES {
            let s = builtin(name).unwrap();
            s.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!s.geometry.triangles.is_empty());
        }
        let e = builtin("nope").unwrap_err().to_string();
        assert!(e.contains("builtin:nope") && e.contains("cornell"), "{e}");
    }

    #[test]
    fn sphere_faces_outwards() {
        let mut g = Geometry::default();
        push_sphere(&mut g, Vec3::ZERO, 1.0, 16, 8, 0);
        for t in &g.triangles {
            let [a, b, c] = t.map(|i| g.positions[i as usize]);
            let n = (b - a).cross(c - a);
            assert!(n.dot(a + b + c) > 0.0, "inward triangle {t:?}");
        }
        let mut g = Geometry::default();
        push_box(&mut g, Vec3::ONE, Vec3::splat(0.5), Quat::from_rotation_y(0.3), 0);
        for t in &g.triangles {
            let [a, b, c] = t.map(|i| g.positions[i as usize]);
            let n = (b - a).cross(c - a);
            assert!(
                n.dot((a + b + c) / 3.0 - Vec3::ONE) > 0.0,
                "inward box face {t:?}"
            );
        }
    }
}
