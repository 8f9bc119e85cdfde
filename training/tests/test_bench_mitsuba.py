"""Tests for bench_mitsuba.py: the GLB loader against facts stated independently of it
(shared/scenes/README.md, scene.json, the glTF spec), and, only where mitsuba is installed,
the Mitsuba scene it builds.

The cbox tests skip when the shared scenes are absent (a bare clone has no ../shared). Set
SUBPIXEL_SCENES to a scenes folder to use another location."""

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest

import bench_mitsuba as bm


def _scenes_root() -> Path:
    env = os.environ.get("SUBPIXEL_SCENES")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / ".." / "shared" / "scenes"


CBOX = _scenes_root() / "cbox"
needs_cbox = pytest.mark.skipif(
    not (CBOX / "scene.json").is_file() or not (CBOX / "scene.glb").is_file(),
    reason=f"shared scenes not found at {CBOX} (set SUBPIXEL_SCENES)",
)


# --- glTF reader on a GLB made here (always runs) -----------------------------------------


def _make_glb(doc: dict, binary: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _triangle_glb(tmp_path, node: dict, interleaved: bool, index_type: int) -> Path:
    """One triangle (0,0,0) (1,0,0) (0,1,0) facing +Z, POSITION and NORMAL either packed or
    interleaved in one bufferView, uint16 or uint32 indices."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    nrm = np.array([[0, 0, 1]] * 3, np.float32)
    idx = np.array([0, 1, 2], np.uint16 if index_type == 5123 else np.uint32)
    if interleaved:
        vtx = np.concatenate([pos, nrm], axis=1).tobytes()  # stride 24
        views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(vtx), "byteStride": 24}]
        accessors = [
            {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": 3, "type": "VEC3"},
        ]
        data = vtx
    else:
        data = pos.tobytes() + nrm.tobytes()
        views = [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 36},
        ]
        accessors = [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"},
        ]
    views.append({"buffer": 0, "byteOffset": len(data), "byteLength": idx.nbytes})
    accessors.append({"bufferView": len(views) - 1, "componentType": index_type, "count": 3, "type": "SCALAR"})
    data += idx.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(data)}],
        "bufferViews": views,
        "accessors": accessors,
        "materials": [
            {
                "pbrMetallicRoughness": {"baseColorFactor": [0.25, 0.5, 0.75, 1.0]},
                "emissiveFactor": [1.0, 0.5, 0.0],
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
            }
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "nodes": [{"children": [1], "translation": [0.0, 0.0, 5.0]}, dict(node, mesh=0)],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    path = tmp_path / "tri.glb"
    path.write_bytes(_make_glb(doc, data))
    return path


@pytest.mark.parametrize("interleaved", [False, True])
@pytest.mark.parametrize("index_type", [5123, 5125])
def test_reader_layouts(tmp_path, interleaved, index_type):
    (prim,) = bm.load_gltf_primitives(_triangle_glb(tmp_path, {}, interleaved, index_type))
    np.testing.assert_allclose(prim.positions, [[0, 0, 5], [1, 0, 5], [0, 1, 5]])
    np.testing.assert_allclose(prim.normals, [[0, 0, 1]] * 3)
    assert prim.indices.tolist() == [[0, 1, 2]]
    assert prim.material.base_color == (0.25, 0.5, 0.75)
    assert prim.material.radiance == (4.0, 2.0, 0.0) and prim.emissive


def test_node_transforms_and_mirroring(tmp_path):
    # Child: scale x by -2 (a mirror), then the parent translates z by 5. The mirror must flip
    # the winding so the front face still agrees with the (inverse-transpose) normal.
    (prim,) = bm.load_gltf_primitives(_triangle_glb(tmp_path, {"scale": [-2.0, 1.0, 1.0]}, False, 5125))
    np.testing.assert_allclose(prim.positions, [[0, 0, 5], [-2, 0, 5], [0, 1, 5]])
    np.testing.assert_allclose(prim.normals, [[0, 0, 1]] * 3, atol=1e-6)
    p = prim.positions[prim.indices[0]]
    assert np.cross(p[1] - p[0], p[2] - p[0])[2] > 0
    # A 90 degree rotation about +Y given as a column-major matrix maps +Z normals to +X.
    m = np.eye(4)
    m[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]
    (prim,) = bm.load_gltf_primitives(
        _triangle_glb(tmp_path, {"matrix": m.T.ravel().tolist()}, False, 5125)
    )
    np.testing.assert_allclose(prim.normals, [[1, 0, 0]] * 3, atol=1e-6)
    np.testing.assert_allclose(prim.positions[1], [0, 0, 4], atol=1e-6)


def test_rejects_non_glb(tmp_path):
    bad = tmp_path / "x.glb"
    bad.write_bytes(b"not a glb file at all")
    with pytest.raises(bm.GltfError):
        bm.read_glb(bad)


def test_llvm_version_from_file_names():
    assert bm.llvm_major_from_path("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert bm.llvm_major_from_path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert bm.llvm_major_from_path("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert bm.llvm_major_from_path("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert bm.llvm_major_from_path("/usr/lib/llvm-16/lib/libLLVM.so") == 16


# --- the shared Cornell box (skips without ../shared/scenes) ------------------------------


@pytest.fixture(scope="module")
def cbox():
    return bm.load_scene(CBOX)


def _by_colour(scene, rgb):
    hits = [p for p in scene.primitives if np.allclose(p.material.base_color, rgb, atol=1e-3)]
    assert hits, f"no primitive with base colour {rgb}"
    return hits


@needs_cbox
def test_cbox_counts(cbox):
    # shared/scenes/README.md: 38 triangles, 5 materials, one area light.
    assert cbox.triangle_count == 38
    assert len(cbox.primitives) == 5
    assert sum(p.emissive for p in cbox.primitives) == 1
    assert not any(p.material.double_sided for p in cbox.primitives)  # "All materials are one-sided"


@needs_cbox
def test_cbox_light(cbox):
    (light,) = [p for p in cbox.primitives if p.emissive]
    # README: radiance (20.71, 10.85, 2.77); luminaire 130 x 105; reflectance (0.776, 0.780, 0.776).
    np.testing.assert_allclose(light.material.radiance, (20.71, 10.85, 2.77), atol=0.01)
    np.testing.assert_allclose(light.material.base_color, (0.776, 0.780, 0.776), atol=1e-3)
    tri = light.positions[light.indices]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert 0.5 * np.linalg.norm(cross, axis=1).sum() == pytest.approx(130 * 105, rel=1e-3)
    # One-sided emission from the CCW front face: it must face down into the box (-Y).
    assert (cross[:, 1] < 0).all()


@needs_cbox
def test_cbox_materials(cbox):
    # README: white/box (0.735, 0.736, 0.736), red (0.491, 0.049, 0.051), green (0.068, 0.398, 0.086).
    assert len(_by_colour(cbox, (0.735, 0.736, 0.736))) == 2
    _by_colour(cbox, (0.491, 0.049, 0.051))
    _by_colour(cbox, (0.068, 0.398, 0.086))


@needs_cbox
def test_cbox_winding_matches_normals(cbox):
    # The index order is read correctly when every CCW face normal agrees with the NORMALs.
    for p in cbox.primitives:
        assert p.normals is not None
        tri = p.positions[p.indices]
        face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        vn = p.normals[p.indices].sum(axis=1)
        assert (np.einsum("ij,ij->i", face, vn) > 0).all(), p.name
        np.testing.assert_allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-5)


@needs_cbox
def test_cbox_bounds(cbox):
    lo, hi = cbox.bounds()
    # "about 550 across": the Cornell box data is 556 x 548.8 x 559.2 with a corner at 0.
    np.testing.assert_allclose(lo, [0, 0, 0], atol=1e-3)
    np.testing.assert_allclose(hi, [556.0, 548.8, 559.2], atol=0.01)


@needs_cbox
def test_cbox_camera(cbox):
    meta = json.loads((CBOX / "scene.json").read_text())
    cam = cbox.camera
    assert cam.position == (278.0, 273.0, -800.0)
    assert cam.target == (278.0, 273.0, -799.0)
    assert cam.up == (0.0, 1.0, 0.0)
    assert cam.yfov_deg == pytest.approx(39.3077)
    assert cam.yfov_deg == meta["camera"]["yfov_deg"]
    assert cbox.film == (256, 256)


# --- Mitsuba (skips without mitsuba) --------------------------------------------------------


@needs_cbox
def test_cbox_renders_in_mitsuba(tmp_path):
    pytest.importorskip("mitsuba")
    # scalar_rgb needs no libLLVM and renders 32x32 at 16 spp in well under a second.
    r = bm.run_benchmark(CBOX, width=32, height=32, spp=16, repeats=1, variant="scalar_rgb",
                         threads=1, out=str(tmp_path / "cbox.exr"))
    assert r["triangles"] == 38 and r["paths_per_render"] == 32 * 32 * 16
    assert r["paths_per_s"] > 0 and r["median_s"] > 0 and r["threads"] >= 1
    assert r["rr_depth"] == 3 and r["max_depth"] == 8
    assert r["contended"] is False  # only judged for the JIT variants
    mean = np.array(r["image_mean_rgb"])
    # A lit box under a warm light: not black, red > green > blue on average.
    assert mean.min() > 0.005 and mean[0] > mean[1] > mean[2]
    assert (tmp_path / "cbox.exr").stat().st_size > 0
    json.dumps(r)  # the --json record must be serialisable


@needs_cbox
def test_cbox_walls_and_light_in_mitsuba(cbox):
    mi = pytest.importorskip("mitsuba")
    bm.setup_mitsuba("scalar_rgb", threads=None)
    # max_depth 1: emitters seen directly, nothing else; the light quad must show its radiance.
    scene = mi.load_dict(bm.build_mitsuba_dict(cbox, 64, 64, 4, max_depth=1, rr_depth=3))
    img = np.array(mi.render(scene, spp=4))
    assert np.isclose(img.reshape(-1, 3), [20.71, 10.85, 2.77], atol=0.05).all(axis=1).any()
    # Full paths: the red wall is on the image left, the green wall on the right (Mitsuba's
    # camera, as in cbox.xml, and as our glTF camera node places them).
    scene = mi.load_dict(bm.build_mitsuba_dict(cbox, 64, 64, 16, max_depth=8, rr_depth=3))
    img = np.array(mi.render(scene, spp=16))
    left, right = img[20:44, 2:6].mean(axis=(0, 1)), img[20:44, 58:62].mean(axis=(0, 1))
    assert left[0] > 3 * left[1] and right[1] > 2 * right[0]


def _mat(**kw):
    mat = dict(name="m", base_color=(0.5, 0.25, 0.125), radiance=(0.0, 0.0, 0.0), double_sided=False,
               roughness=1.0, metallic=0.0, ior=1.5)
    mat.update(kw)
    return bm.Material(**mat)


def test_bsdf_descriptions():
    p = _mat(roughness=0.5, metallic=0.25, ior=1.5)
    assert bm.bsdf_dict(p) == {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.25, 0.125]}}
    d = bm.bsdf_dict(p, "principled")
    assert d["type"] == "principled" and d["base_color"]["value"] == [0.5, 0.25, 0.125]
    assert d["roughness"] == 0.5 and d["metallic"] == 0.25
    # Mitsuba's principled: specular 0.5 is a normal-incidence reflectance of 0.04 (ior 1.5).
    assert np.isclose(d["specular"], 0.5)
    assert np.isclose(bm.specular_level(1.0), 0.0) and bm.specular_level(2.0) > 0.5
    assert bm.bsdf_dict(_mat(double_sided=True), "principled")["type"] == "twosided"
    with pytest.raises(ValueError, match="bsdf must be one of"):
        bm.bsdf_dict(p, "glass")


@needs_cbox
def test_cbox_materials_are_rough_dielectrics(cbox):
    # shared/scenes/cbox/scene.glb: every material metallicFactor 0, roughnessFactor 1.
    assert all(p.material.metallic == 0.0 and p.material.roughness == 1.0 and p.material.ior == 1.5
               for p in cbox.primitives)


@needs_cbox
def test_cbox_renders_with_the_principled_bsdf_in_mitsuba(cbox):
    mi = pytest.importorskip("mitsuba")
    bm.setup_mitsuba("scalar_rgb", threads=None)
    diffuse = np.array(mi.render(mi.load_dict(bm.build_mitsuba_dict(cbox, 24, 24, 64, 8, 3)), spp=64))
    principled = np.array(mi.render(mi.load_dict(bm.build_mitsuba_dict(cbox, 24, 24, 64, 8, 3, "principled")), spp=64))
    # The same box: a few percent apart (Disney diffuse retro-reflection at roughness 1 adds
    # some, the specular layer takes some), measured 1.06-1.09x at 256 spp.
    ratio = principled.mean(axis=(0, 1)) / diffuse.mean(axis=(0, 1))
    assert np.all(ratio > 0.95) and np.all(ratio < 1.2), ratio
