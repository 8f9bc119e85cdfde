//! Loader tests over small files written to a temporary folder.

use super::gltf::{base64_decode, load_gltf_checked, percent_decode};
use super::*;
use crate::render::camera::CameraPathSpec;
use crate::render::load_scene;
use glam::Vec3;

#[test]
fn base64_and_percent() {
    assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
    assert_eq!(base64_decode("AAEC").unwrap(), vec![0, 1, 2]);
    assert!(base64_decode("a*b").is_none());
    assert_eq!(percent_decode("a%20b.png"), "a b.png");
    assert_eq!(percent_decode("100%"), "100%");
}

fn base64_encode(b: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in b.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A one-triangle glTF (positions + u16 indices in a data URI); `extra` is merged into
/// the root object, `node` into the node.
fn tiny_gltf(extra: &str, node: &str, material: &str) -> String {
    let mut bytes = Vec::new();
    for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
        for c in v {
            bytes.extend(c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0] {
        bytes.extend(i.to_le_bytes());
    }
    format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0 {node}}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1 {material}}}]}}],
        "accessors": [
          {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
          {{"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}}],
        "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 36}}, {{"buffer": 0, "byteOffset": 36, "byteLength": 6}}],
        "buffers": [{{"byteLength": 44, "uri": "data:application/octet-stream;base64,{}"}}] {extra}}}"#,
        base64_encode(&bytes)
    )
}

fn tmp(name: &str) -> PathBuf {
    crate::io::test_dir(&format!("loader-{name}"))
}

/// [`tiny_gltf`] whose material has the image at `uri` as its base colour texture.
fn textured_gltf(uri: &str) -> String {
    let extra = format!(
        r#", "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}],
        "textures": [{{"source": 0}}], "images": [{{"uri": "{uri}"}}]"#
    );
    tiny_gltf(&extra, "", r#", "material": 0"#)
}

/// Writes `ok.gltf` (a [`tiny_gltf`]) and a `scene.json` loading it with the environment
/// map `file` into `d`; returns the path of `scene.json`.
fn scene_with_environment(d: &Path, file: &str) -> PathBuf {
    std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
    let json = d.join("scene.json");
    let text = format!(r#"{{"gltf": "ok.gltf", "environment": {{"file": "{file}", "scale": 1.0}}}}"#);
    std::fs::write(&json, text).unwrap();
    json
}

/// The message of the error loading `path` gives.
fn load_err(path: &Path) -> String {
    load_scene(path.to_str().unwrap()).unwrap_err().to_string()
}

/// Writes `text` to `d/name` and returns the message of the error loading it gives.
fn write_load_err(d: &Path, name: &str, text: impl AsRef<[u8]>) -> String {
    let p = d.join(name);
    std::fs::write(&p, text).unwrap();
    load_err(&p)
}

#[test]
fn tiny_gltf_loads_with_node_transform_and_mirroring() {
    let d = tmp("ok");
    let p = d.join("t.gltf");
    std::fs::write(&p, tiny_gltf("", r#", "translation": [0, 0, -5]"#, "")).unwrap();
    let s = load_scene(p.to_str().unwrap()).unwrap();
    assert_eq!(s.geometry.triangles.len(), 1);
    assert_eq!(s.geometry.positions[1], Vec3::new(1.0, 0.0, -5.0));
    // Default material: glTF defaults.
    assert_eq!(s.materials.last().unwrap().metallic, 1.0);
    // A mirroring transform keeps the front face (winding flipped).
    std::fs::write(&p, tiny_gltf("", r#", "scale": [-1, 1, 1]"#, "")).unwrap();
    let s = load_scene(p.to_str().unwrap()).unwrap();
    let [a, b, c] = s.geometry.triangles[0].map(|i| s.geometry.positions[i as usize]);
    assert!((b - a).cross(c - a).z > 0.0, "front face must still face +z");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn bad_files_are_named_errors() {
    let d = tmp("bad");
    // Malformed JSON.
    let e = write_load_err(&d, "broken.gltf", "{ not json");
    assert!(e.contains("broken.gltf") && e.contains("malformed"), "{e}");
    // Unsupported required extension.
    let ext = r#", "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"]"#;
    let e = write_load_err(&d, "draco.gltf", tiny_gltf(ext, "", ""));
    assert!(
        e.contains("draco.gltf") && e.contains("KHR_draco_mesh_compression"),
        "{e}"
    );
    // Missing texture file.
    let e = write_load_err(&d, "tex.gltf", textured_gltf("missing_albedo.png"));
    assert!(e.contains("missing_albedo.png") && e.contains("tex.gltf"), "{e}");
    // Undecodable texture.
    std::fs::write(d.join("missing_albedo.png"), b"not a png").unwrap();
    let e = load_err(&d.join("tex.gltf"));
    assert!(e.contains("missing_albedo.png") && e.contains("decode"), "{e}");
    // Unreadable / corrupt environment map.
    let json = scene_with_environment(&d, "sky.hdr");
    let e = load_err(&d);
    assert!(e.contains("sky.hdr"), "{e}");
    std::fs::write(d.join("sky.hdr"), b"#?RADIANCE\ngarbage").unwrap();
    let e = load_err(&json);
    assert!(e.contains("sky.hdr") && e.contains("environment"), "{e}");
    // Malformed scene.json.
    std::fs::write(&json, r#"{"environment": null}"#).unwrap();
    let e = load_err(&json);
    assert!(e.contains("scene.json") && e.contains("gltf"), "{e}");
    // Missing file, unknown extension.
    let e = load_err(&d.join("nope.glb"));
    assert!(e.contains("nope.glb"), "{e}");
    std::fs::write(d.join("x.obj"), "").unwrap();
    let e = load_err(&d.join("x.obj"));
    assert!(e.contains("x.obj"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 12 item 9: a FIFO or a device as glTF, buffer, image or environment map is
/// refused (regular files only) instead of blocking or reading forever.
#[cfg(unix)]
#[test]
fn special_files_are_refused() {
    let d = tmp("special");
    let fifo = d.join("fifo.bin");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    assert!(made.map(|s| s.success()).unwrap_or(false), "mkfifo");
    let e = load_err(Path::new("/dev/zero"));
    assert!(e.contains("/dev/zero"), "{e}");
    std::os::unix::fs::symlink("/dev/zero", d.join("zero.gltf")).unwrap();
    let e = load_err(&d.join("zero.gltf"));
    assert!(e.contains("zero.gltf") && e.contains("not a regular file"), "{e}");
    std::os::unix::fs::symlink(&fifo, d.join("fifo.glb")).unwrap();
    let e = load_err(&d.join("fifo.glb"));
    assert!(e.contains("not a regular file"), "{e}");
    // A buffer and an image that are a FIFO and /dev/zero.
    let data_uri = tiny_gltf("", "", "");
    let with_buffer = |uri: &str| {
        let at = data_uri.find("data:application").unwrap();
        let end = at + data_uri[at..].find('"').unwrap();
        format!("{}{uri}{}", &data_uri[..at], &data_uri[end..])
    };
    for uri in ["fifo.bin", "/dev/zero"] {
        let e = write_load_err(&d, "buf.gltf", with_buffer(uri));
        assert!(
            e.contains("not a regular file") && e.contains("buffer 0"),
            "{uri}: {e}"
        );
    }
    let e = write_load_err(&d, "tex.gltf", textured_gltf("fifo.bin"));
    assert!(e.contains("fifo.bin") && e.contains("not a regular file"), "{e}");
    let e = load_err(&scene_with_environment(&d, "fifo.bin"));
    assert!(e.contains("fifo.bin") && e.contains("not a regular file"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 12 item 6: glTF files that made the `gltf` crate panic (its message and a
/// backtrace reached the user before the clean error) are refused from their JSON, by
/// the loader itself, without any panic.
#[test]
fn gltf_crate_panics_are_prevented() {
    let d = tmp("panics");
    let json: serde_json::Value = serde_json::from_str(&tiny_gltf("", "", "")).unwrap();
    type Edit = fn(&mut serde_json::Value);
    let cases: [(&str, Edit, &str); 6] = [
        (
            "indices of float VEC3",
            |j| j["meshes"][0]["primitives"][0]["indices"] = 0.into(),
            "indices: accessors[0] is VEC3 of componentType 5126, expected SCALAR",
        ),
        (
            "POSITION accessor out of range",
            |j| j["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 9.into(),
            "attributes.POSITION: accessor 9 does not exist",
        ),
        (
            "indices accessor out of range",
            |j| j["meshes"][0]["primitives"][0]["indices"] = 7.into(),
            "indices: accessor 7 does not exist",
        ),
        (
            "byteStride smaller than the element",
            |j| j["bufferViews"][0]["byteStride"] = 4.into(),
            "byteStride 4 is smaller than the 12-byte elements",
        ),
        (
            "TEXCOORD_0 of unsigned int",
            |j| {
                j["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2.into();
                j["accessors"].as_array_mut().unwrap().push(serde_json::json!(
                    {"bufferView": 0, "componentType": 5125, "count": 3, "type": "VEC2"}
                ));
            },
            "TEXCOORD_0: accessors[2] is VEC2 of componentType 5125",
        ),
        (
            "accessor past its view",
            |j| j["accessors"][0]["count"] = 1_000_000.into(),
            "runs past bufferViews[0]",
        ),
    ];
    for (name, edit, want) in cases {
        let mut j = json.clone();
        edit(&mut j);
        let p = d.join("m.gltf");
        std::fs::write(&p, j.to_string()).unwrap();
        let r = std::panic::catch_unwind(|| load_gltf_checked(&p));
        let e = r
            .unwrap_or_else(|_| panic!("{name}: the loader panicked"))
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.gltf") && e.contains(want), "{name}: {e}");
    }
    std::fs::remove_dir_all(&d).ok();
}

/// Issue 12 item 7: degenerate cameras in scene.json or glTF are errors naming the
/// field, not black frames or NaN motion.
#[test]
fn degenerate_cameras_are_named_errors() {
    let d = tmp("cams");
    std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
    let json = d.join("scene.json");
    let cam = |c: &str, path: &str| {
        std::fs::write(&json, format!(r#"{{"gltf": "ok.gltf", "camera": {c} {path}}}"#)).unwrap();
        load_scene(json.to_str().unwrap())
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let good = r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40}"#;
    cam(good, "").unwrap();
    for (c, want) in [
        (
            r#"{"position": [0, 0, 3], "target": [0, 0, 3], "yfov_deg": 40}"#,
            "target",
        ),
        (
            r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 0, 1], "yfov_deg": 40}"#,
            "up",
        ),
        (
            r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 0, 0], "yfov_deg": 40}"#,
            "up",
        ),
        (
            r#"{"position": [1e39, 0, 3], "target": [0, 0, 0], "yfov_deg": 40}"#,
            "position",
        ),
        (
            r#"{"position": [0, 0, 3], "target": [0, 0, 0], "yfov_deg": 0}"#,
            "yfov",
        ),
    ] {
        let e = cam(c, "").unwrap_err();
        assert!(e.contains("scene.json") && e.contains(want), "{c}: {e}");
    }
    for (p, want) in [
        (
            r#", "camera_path": {"type": "orbit", "degrees_per_frame": 1e39}"#,
            "degrees_per_frame",
        ),
        (
            r#", "camera_path": {"type": "orbit", "degrees_per_frame": 1e30}"#,
            "degrees_per_frame",
        ),
        (
            r#", "camera_path": {"type": "flythrough", "keys": [{"position": [0, 0, 3], "target": [0, 0, 0]}, {"position": [1, 1, 1], "target": [1, 1, 1]}]}"#,
            "keys[1]",
        ),
    ] {
        let e = cam(good, p).unwrap_err();
        assert!(e.contains("scene.json") && e.contains(want), "{p}: {e}");
    }
    // A glTF camera with yfov 0.
    let extra = r#", "cameras": [{"type": "perspective", "perspective": {"yfov": 0.0, "znear": 0.1}}]"#;
    let e = write_load_err(&d, "cam.gltf", tiny_gltf(extra, r#", "camera": 0"#, ""));
    assert!(
        e.contains("cam.gltf") && e.contains("yfov") && e.contains("node 0"),
        "{e}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// A buffer file longer than its declared byteLength loads (only the declared bytes are
/// read: `read_regular`'s cap, tested in `io`).
#[test]
fn buffers_are_read_up_to_their_declared_length() {
    let d = tmp("cap");
    let g = tiny_gltf("", "", "");
    let at = g.find("data:application").unwrap();
    let end = at + g[at..].find('"').unwrap();
    let b64 = &g[at + "data:application/octet-stream;base64,".len()..end];
    let mut bytes = base64_decode(b64).unwrap();
    bytes.extend(std::iter::repeat_n(0xAB, 1 << 20));
    std::fs::write(d.join("big.bin"), &bytes).unwrap();
    let p = d.join("cap.gltf");
    std::fs::write(&p, format!("{}big.bin{}", &g[..at], &g[end..])).unwrap();
    let s = load_scene(p.to_str().unwrap()).unwrap();
    assert_eq!(s.geometry.triangles.len(), 1);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn sidecar_environment_and_camera() {
    let d = tmp("side");
    std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
    // A 4x2 RGB float EXR environment, via the image crate.
    let img = image::Rgb32FImage::from_fn(4, 2, |x, y| image::Rgb([x as f32, y as f32, 1.0]));
    image::DynamicImage::ImageRgb32F(img)
        .save(d.join("env.exr"))
        .unwrap();
    std::fs::write(
        d.join("scene.json"),
        r#"{"gltf": "ok.gltf",
            "environment": {"file": "env.exr", "scale": 2.0, "rotation_y_deg": 90.0,
                            "mapping": "mitsuba_latlong: ..."},
            "camera": {"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40},
            "film": [64, 32],
            "camera_path": {"type": "orbit", "degrees_per_frame": 2.0}}"#,
    )
    .unwrap();
    let s = load_scene(d.to_str().unwrap()).unwrap();
    let e = s.environment.as_ref().unwrap();
    assert_eq!((e.width, e.height, e.scale), (4, 2, 2.0));
    assert_eq!(s.film, (64, 32));
    assert!((s.camera.yfov - 40f32.to_radians()).abs() < 1e-6);
    assert_eq!(
        s.camera_path,
        Some(CameraPathSpec::Orbit {
            degrees_per_frame: Some(2.0)
        })
    );
    // Mitsuba lat-long: with to_world = rotate 90 deg about +y, world +x maps to map
    // direction +z: u = atan2(0, -1) / 2pi = 0.5 -> column 2; v = 0.5 -> row 1.
    let c = e.radiance(Vec3::X);
    assert_eq!(c, Vec3::new(2.0, 1.0, 1.0) * 2.0);
    // World -z maps to map +x (rotated): u = atan2(1, 0) / 2pi = 0.25 -> column 1.
    let c = e.radiance(Vec3::NEG_Z);
    assert_eq!(c, Vec3::new(1.0, 1.0, 1.0) * 2.0);
    assert!(e.portals.is_empty());
    std::fs::remove_dir_all(&d).ok();
}

/// `environment.portals` of scene.json: read in world space; degenerate or non-finite ones
/// are errors naming the file and the portal.
#[test]
fn sidecar_portals() {
    let d = tmp("portals");
    let json = scene_with_environment(&d, "env.exr");
    let img = image::Rgb32FImage::from_fn(4, 2, |_, _| image::Rgb([1.0, 1.0, 1.0]));
    image::DynamicImage::ImageRgb32F(img)
        .save(d.join("env.exr"))
        .unwrap();
    let with = |portals: &str| {
        let text =
            format!(r#"{{"gltf": "ok.gltf", "environment": {{"file": "env.exr", "portals": {portals}}}}}"#);
        std::fs::write(&json, text).unwrap();
        load_scene(json.to_str().unwrap())
    };
    let s = with(r#"[{"corner": [0, 1, -2], "u": [2, 0, 0], "v": [0, 1.5, 0]}]"#).unwrap();
    let p = &s.environment.as_ref().unwrap().portals;
    assert_eq!(p.len(), 1);
    assert_eq!(p[0].corner, Vec3::new(0.0, 1.0, -2.0));
    assert!((p[0].area() - 3.0).abs() < 1e-6);
    for bad in [
        r#"[{"corner": [0, 0, 0], "u": [1, 0, 0], "v": [2, 0, 0]}]"#,
        r#"[{"corner": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0]}, {"corner": [0, 0, 0], "u": [0, 0, 0], "v": [0, 1, 0]}]"#,
    ] {
        let e = with(bad).unwrap_err().to_string();
        assert!(
            e.contains("scene.json") && e.contains("environment.portals["),
            "{e}"
        );
    }
    let e = with(r#"[{"corner": [0, 0], "u": [1, 0, 0], "v": [0, 1, 0]}]"#)
        .unwrap_err()
        .to_string();
    assert!(e.contains("scene.json") && e.contains("malformed"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}
