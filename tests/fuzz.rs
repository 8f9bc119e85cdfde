//! Issue 12: a bounded-time fuzz corpus. A few hundred deterministic mutants each of a
//! small glTF, an EXR frame and a safetensors weights file must each load or give a clean
//! error: no panic (not even one caught and turned into an error), no abort, no case
//! slower than a few seconds.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng, rngs::StdRng};
use subpixel::io::exr::{FrameFile, read_frame, write_frame};
use subpixel::nn::HostTensor;
use subpixel::ssr::{HostFrame, Weights};

static PANICS: AtomicUsize = AtomicUsize::new(0);

/// Longest any one mutant may take.
const CASE_LIMIT: Duration = Duration::from_secs(5);

fn tmp() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("subpixel-fuzz-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs one mutant, timing it; the result must be Ok or Err (a panic is counted by the hook).
fn case<T, E: std::fmt::Display>(what: &str, i: usize, f: impl FnOnce() -> Result<T, E>) -> bool {
    let t = Instant::now();
    let ok = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r.is_ok(),
        Err(_) => panic!("{what} mutant {i} panicked"),
    };
    assert!(
        t.elapsed() < CASE_LIMIT,
        "{what} mutant {i} took {:?}",
        t.elapsed()
    );
    ok
}

/// Two triangles in a glTF whose buffer is a file next to it, as a JSON value.
fn small_gltf(dir: &Path) -> serde_json::Value {
    let mut bin = Vec::new();
    for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.], [1., 1., 0.]] {
        v.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    for n in [[0f32, 0., 1.]; 4] {
        n.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    for uv in [[0f32, 0.], [1., 0.], [0., 1.], [1., 1.]] {
        uv.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 2, 1, 3] {
        bin.extend(i.to_le_bytes());
    }
    std::fs::write(dir.join("buf.bin"), &bin).unwrap();
    serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [0, 0, -3]}, {"camera": 0, "translation": [0, 0, 1]}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.2, 0.2, 1.0], "metallicFactor": 0.0}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                                    "indices": 3, "material": 0}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 32},
            {"buffer": 0, "byteOffset": 128, "byteLength": 12}],
        "buffers": [{"byteLength": 140, "uri": "buf.bin"}]
    })
}

/// Every leaf of `v` as a JSON pointer.
fn leaves(v: &serde_json::Value, at: String, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => m.iter().for_each(|(k, x)| leaves(x, format!("{at}/{k}"), out)),
        serde_json::Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| leaves(x, format!("{at}/{i}"), out)),
        _ => out.push(at),
    }
}

fn mutate_json(base: &serde_json::Value, rng: &mut StdRng) -> serde_json::Value {
    use serde_json::json;
    const INTEGERS: [i64; 16] = [
        0,
        1,
        2,
        3,
        4,
        7,
        255,
        5120,
        5121,
        5123,
        5125,
        5126,
        65535,
        4294967297,
        -1,
        10_000_000_000,
    ];
    const FLOATS: [f64; 4] = [0.5, 1e300, -1e300, 0.0];
    let types = ["SCALAR", "VEC2", "VEC3", "VEC4", "MAT4", "BOGUS"];
    let mut v = base.clone();
    let mut paths = Vec::new();
    leaves(&v, String::new(), &mut paths);
    for _ in 0..rng.random_range(1..=3) {
        let p = &paths[rng.random_range(0..paths.len())];
        let Some(slot) = v.pointer_mut(p) else { continue };
        *slot = match rng.random_range(0..6) {
            0..=1 => json!(INTEGERS[rng.random_range(0..INTEGERS.len())]),
            2 => json!(FLOATS[rng.random_range(0..FLOATS.len())]),
            3 => json!(types[rng.random_range(0..types.len())]),
            4 => json!(null),
            _ => json!([]),
        };
    }
    // Sometimes a key goes away entirely.
    if rng.random_bool(0.2) {
        let p = &paths[rng.random_range(0..paths.len())];
        if let Some((parent, key)) = p.rsplit_once('/')
            && let Some(serde_json::Value::Object(m)) = v.pointer_mut(parent)
        {
            m.remove(key);
        }
    }
    v
}

fn mutate_bytes(base: &[u8], rng: &mut StdRng, hot: usize) -> Vec<u8> {
    let mut b = base.to_vec();
    match rng.random_range(0..4) {
        // Truncation.
        0 => b.truncate(rng.random_range(0..b.len())),
        // A few random bytes, mostly in the header region.
        1 | 2 => {
            for _ in 0..rng.random_range(1..=8) {
                let end = if rng.random_bool(0.8) {
                    hot.min(b.len())
                } else {
                    b.len()
                };
                let i = rng.random_range(0..end);
                b[i] = rng.random();
            }
        }
        // An "interesting" 32-bit integer written over the header.
        _ => {
            const INTS: [u32; 7] = [0, 1, 0x7fff_ffff, 0xffff_ffff, 100_000, 0x8000_0000, 65_536];
            let i = rng.random_range(0..hot.min(b.len()).saturating_sub(4).max(1));
            let v = INTS[rng.random_range(0..INTS.len())].to_le_bytes();
            for (k, x) in v.iter().enumerate() {
                if let Some(slot) = b.get_mut(i + k) {
                    *slot = *x;
                }
            }
        }
    }
    b
}

#[test]
fn mutants_load_or_give_clean_errors() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICS.fetch_add(1, Ordering::SeqCst);
        default_hook(info);
    }));
    let t0 = Instant::now();
    let dir = tmp();
    // `SUBPIXEL_FUZZ_SEED` and `SUBPIXEL_FUZZ_SCALE` (a multiplier of the case counts) run
    // other or longer corpora by hand; the defaults are what CI runs.
    let env = |k: &str, d: u64| std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d);
    let mut rng = StdRng::seed_from_u64(env("SUBPIXEL_FUZZ_SEED", 12));
    let scale = env("SUBPIXEL_FUZZ_SCALE", 1) as usize;

    // glTF: JSON-level mutants (types, indices, strides, counts, offsets, missing keys) and
    // a few byte-level ones.
    let base = small_gltf(&dir);
    let path = dir.join("m.gltf");
    std::fs::write(&path, base.to_string()).unwrap();
    let s = subpixel::render::load_scene(path.to_str().unwrap()).unwrap();
    assert_eq!(s.geometry.triangles.len(), 2, "the unmutated glTF loads");
    let mut loaded = 0;
    let n = 400 * scale;
    for i in 0..n {
        let text = if i % 10 == 9 {
            let b = mutate_bytes(base.to_string().as_bytes(), &mut rng, usize::MAX);
            String::from_utf8_lossy(&b).into_owned()
        } else {
            mutate_json(&base, &mut rng).to_string()
        };
        std::fs::write(&path, &text).unwrap();
        if case("glTF", i, || subpixel::render::load_scene(path.to_str().unwrap())) {
            loaded += 1;
        }
    }
    assert!(
        loaded > 0 && loaded < n,
        "a mix of loadable and broken mutants ({loaded})"
    );

    // EXR frame: byte mutants, mostly of the header.
    let frame = HostFrame {
        color: HostTensor::from_fn(8, 6, 3, |x, y, c| (x + y + c) as f32 * 0.1),
        mask: HostTensor::from_fn(8, 6, 1, |x, y, _| ((x + y) % 2) as f32),
        albedo: HostTensor::from_fn(8, 6, 3, |_, _, _| 0.5),
        normal: HostTensor::from_fn(8, 6, 3, |_, _, c| (c == 2) as u32 as f32),
        shadow: HostTensor::from_fn(8, 6, 3, |x, _, _| x as f32),
        transparent: HostTensor::zeros(8, 6, 3),
        depth: HostTensor::from_fn(8, 6, 1, |_, y, _| y as f32 * 0.1),
        metallic: HostTensor::zeros(8, 6, 1),
        roughness: HostTensor::from_fn(8, 6, 1, |_, _, _| 0.5),
        motion: HostTensor::from_fn(8, 6, 2, |x, _, _| x as f32 * 0.25),
        background: None,
    };
    let exr = dir.join("frame_0000.exr");
    write_frame(
        &exr,
        &FrameFile {
            frame: Some(frame.clone()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        read_frame(&exr).unwrap().frame.unwrap(),
        frame,
        "the unmutated frame reads back"
    );
    let exr_bytes = std::fs::read(&exr).unwrap();
    for i in 0..250 * scale {
        std::fs::write(&exr, mutate_bytes(&exr_bytes, &mut rng, 1200)).unwrap();
        case("EXR", i, || read_frame(&exr));
    }

    // safetensors weights: byte mutants, mostly of the 8-byte length and the JSON header.
    let weights =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden_weights.safetensors"))
            .unwrap();
    Weights::from_bytes(&weights, "w.safetensors").unwrap();
    let header = 8 + u64::from_le_bytes(weights[..8].try_into().unwrap()) as usize;
    for i in 0..250 * scale {
        let b = mutate_bytes(&weights, &mut rng, header);
        case("safetensors", i, || Weights::from_bytes(&b, "w.safetensors"));
    }

    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(
        PANICS.load(Ordering::SeqCst),
        0,
        "panics (caught or not) during the corpus"
    );
    assert!(
        t0.elapsed() < Duration::from_secs(120 * scale as u64),
        "corpus took {:?}",
        t0.elapsed()
    );
}
