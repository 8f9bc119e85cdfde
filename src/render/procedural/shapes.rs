//! Geometry primitives scenes are built from: rectangles, walls with holes, boxes, spheres,
//! cylinders.

use glam::{Quat, Vec2, Vec3, Vec4};

use crate::render::scene::Geometry;

/// Appends the rectangle with corner `o` and edges `u`, `v` (front face towards `u x v`),
/// texture coordinates in units of `tile` (u along `u`, v decreasing along `v`, starting at
/// `uv0` at the corner) and tangents along `u`.
pub fn push_rect(g: &mut Geometry, o: Vec3, u: Vec3, v: Vec3, uv0: Vec2, tile: f32, material: u32) {
    let n = u.cross(v).normalize_or_zero();
    let t = u.normalize_or_zero().extend(1.0);
    let (su, sv) = (u.length() / tile, v.length() / tile);
    let uv = [
        uv0,
        uv0 + Vec2::new(su, 0.0),
        uv0 + Vec2::new(su, -sv),
        uv0 + Vec2::new(0.0, -sv),
    ];
    g.push_mesh(
        &[o, o + u, o + u + v, o + v],
        Some(&[n; 4]),
        Some(&uv),
        Some(&[t; 4]),
        &[[0, 1, 2], [0, 2, 3]],
        material,
    );
}

/// Appends a wall: the rectangle `width x height` from corner `o` along the unit directions
/// `u` and `v` (front face towards `u x v`), minus the rectangular holes `[s0, s1, t0, t1]`
/// (in metres along `u` and `v`). Texture coordinates are continuous across the pieces.
#[allow(clippy::too_many_arguments)]
pub fn push_wall(
    g: &mut Geometry,
    o: Vec3,
    u: Vec3,
    v: Vec3,
    width: f32,
    height: f32,
    holes: &[[f32; 4]],
    tile: f32,
    material: u32,
) {
    let mut xs = vec![0.0, width];
    let mut ys = vec![0.0, height];
    for h in holes {
        xs.extend([h[0].clamp(0.0, width), h[1].clamp(0.0, width)]);
        ys.extend([h[2].clamp(0.0, height), h[3].clamp(0.0, height)]);
    }
    for v in [&mut xs, &mut ys] {
        v.sort_by(f32::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-5);
    }
    for j in 0..ys.len() - 1 {
        for i in 0..xs.len() - 1 {
            let (s0, s1, t0, t1) = (xs[i], xs[i + 1], ys[j], ys[j + 1]);
            let (cs, ct) = (0.5 * (s0 + s1), 0.5 * (t0 + t1));
            if holes
                .iter()
                .any(|h| cs > h[0] && cs < h[1] && ct > h[2] && ct < h[3])
            {
                continue;
            }
            push_rect(
                g,
                o + u * s0 + v * t0,
                u * (s1 - s0),
                v * (t1 - t0),
                Vec2::new(s0 / tile, -t0 / tile),
                tile,
                material,
            );
        }
    }
}

/// Appends a box of half-extents `h`, rotated by `rot`, centred at `c` (faces outwards),
/// with texture coordinates in units of `tile` and tangents.
pub fn push_box(g: &mut Geometry, c: Vec3, h: Vec3, rot: Quat, tile: f32, material: u32) {
    let (x, y, z) = (h.x, h.y, h.z);
    let faces = [
        (
            Vec3::new(-x, -y, z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(x, -y, -z),
            Vec3::new(-2. * x, 0., 0.),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(x, -y, z),
            Vec3::new(0., 0., -2. * z),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(-x, -y, -z),
            Vec3::new(0., 0., 2. * z),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(-x, y, z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 0., -2. * z),
        ),
        (
            Vec3::new(-x, -y, -z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 0., 2. * z),
        ),
    ];
    for (o, u, v) in faces {
        push_rect(g, c + rot * o, rot * u, rot * v, Vec2::ZERO, tile, material);
    }
}

/// Appends a UV sphere of radius `r` centred at `c` (faces outwards), with smooth normals,
/// texture coordinates (u around, repeated `repeat` times; v from the north pole) and
/// tangents along u.
pub fn push_sphere(g: &mut Geometry, c: Vec3, r: f32, segments: u32, rings: u32, repeat: f32, material: u32) {
    let uv_scale = Vec2::new(repeat, repeat * 0.5);
    g.push_uv_sphere(c, r, (segments, rings), uv_scale, true, material);
}

/// Appends a closed cylinder of radius `r` and height `h` standing on the point `base`
/// (axis +y), with smooth sides, flat caps, texture coordinates in units of `tile` and
/// tangents.
pub fn push_cylinder(g: &mut Geometry, base: Vec3, r: f32, h: f32, segments: u32, tile: f32, material: u32) {
    let segments = segments.max(3);
    let circumference = std::f32::consts::TAU * r;
    let mut pos = Vec::new();
    let mut nrm = Vec::new();
    let mut uv = Vec::new();
    let mut tan = Vec::new();
    for j in 0..2u32 {
        let y = j as f32 * h;
        for i in 0..=segments {
            let phi = i as f32 / segments as f32 * std::f32::consts::TAU;
            let n = Vec3::new(phi.cos(), 0.0, -phi.sin());
            pos.push(base + r * n + Vec3::Y * y);
            nrm.push(n);
            uv.push(Vec2::new(
                i as f32 / segments as f32 * circumference / tile,
                -y / tile,
            ));
            tan.push(Vec4::new(-phi.sin(), 0.0, -phi.cos(), 1.0));
        }
    }
    let row = segments + 1;
    let mut tris = Vec::new();
    for i in 0..segments {
        let (a, b) = (i, i + 1);
        let (c, d) = (b + row, a + row);
        tris.push([a, b, c]);
        tris.push([a, c, d]);
    }
    g.push_mesh(&pos, Some(&nrm), Some(&uv), Some(&tan), &tris, material);
    // Caps: centre + rim.
    for top in [false, true] {
        let y = if top { h } else { 0.0 };
        let n = if top { Vec3::Y } else { Vec3::NEG_Y };
        let mut p = vec![base + Vec3::Y * y];
        let mut t = vec![Vec2::ZERO];
        for i in 0..segments {
            let phi = i as f32 / segments as f32 * std::f32::consts::TAU;
            let off = Vec3::new(phi.cos(), 0.0, -phi.sin()) * r;
            p.push(base + off + Vec3::Y * y);
            t.push(Vec2::new(off.x, if top { off.z } else { -off.z }) / tile);
        }
        let tris: Vec<[u32; 3]> = (0..segments)
            .map(|i| {
                let (a, b) = (1 + i, 1 + (i + 1) % segments);
                if top { [0, a, b] } else { [0, b, a] }
            })
            .collect();
        let k = p.len();
        g.push_mesh(
            &p,
            Some(&vec![n; k]),
            Some(&t),
            Some(&vec![Vec4::new(1.0, 0.0, 0.0, 1.0); k]),
            &tris,
            material,
        );
    }
}
