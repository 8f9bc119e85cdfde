#!/usr/bin/env python3
"""Time Mitsuba 3 on the scene our path tracer renders, for a CPU speed comparison.

The scene is read from our own glTF (``scene.glb`` + ``scene.json`` in a shared/scenes folder,
by default the Cornell box ``cbox``), not from a Mitsuba XML file, so that both renderers see
exactly the same triangles, colours, light and camera:

* one ``mesh`` per glTF primitive, built from numpy arrays (positions, normals, indices),
  with node transforms applied (the converted scenes have them baked, so they are identities);
* a ``diffuse`` BSDF with the glTF base colour (``twosided`` only when the material is
  ``doubleSided``; the cbox is all one-sided, as in Mitsuba's own cbox.xml), or with
  ``--bsdf principled`` Mitsuba's ``principled`` one (base colour, roughness, metallic, and
  the specular level of the glTF ior: 0.5 for 1.5), the counterpart of the glTF
  metallic-roughness material whose GGX and diffuse lobes our tracer evaluates at every
  vertex: a closer cost per vertex than ``diffuse``'s;
* an ``area`` emitter with radiance = emissiveFactor x KHR_materials_emissive_strength;
* a ``perspective`` sensor from scene.json (fov_axis "y", fov = yfov_deg, look_at), a box
  reconstruction filter, the ``independent`` sampler and the ``path`` integrator
  (next-event estimation with MIS), max_depth 8 and rr_depth 3 by default.

Timing: one untimed render (JIT compilation, kernel cache), then ``--repeats`` timed renders
with seeds 1..N, each forced to completion (dr.eval + dr.sync_thread) inside the timed region.
The figure of merit is paths/s = width * height * spp / median wall time.

Usage (from the repository root):

    python training/bench_mitsuba.py --scene ../shared/scenes/cbox --spp 64 --json

The LLVM variant (``llvm_ad_rgb``, the default) needs a shared libLLVM. Dr.Jit 1.5 accepts
LLVM 15 or newer; on Debian: ``apt-get install libllvm16`` (or ``libllvm19``). The script
looks for it itself when DRJIT_LIBLLVM_PATH is unset. ``--variant scalar_rgb`` runs
without LLVM (one path at a time; much slower, not a fair comparison).

Only the standard library and numpy are needed to import this module and use its glTF
loader; mitsuba is imported when a render is requested.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import re
import resource
import statistics
import struct
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

DEFAULT_SCENE = Path(__file__).resolve().parents[1] / ".." / "shared" / "scenes" / "cbox"

# Dr.Jit 1.5's own check (jit_llvm_init): "requires LLVM 15 or newer for opaque pointer support".
MIN_LLVM_MAJOR = 15
LLVM_INSTALL_HINT = (
    "no usable libLLVM (version >= %d) was found. Install one from Debian, e.g. "
    "`apt-get update && apt-get install libllvm16` (bookworm also has libllvm19), or point "
    "DRJIT_LIBLLVM_PATH at a libLLVM*.so; or run the much slower `--variant scalar_rgb`."
    % MIN_LLVM_MAJOR
)

# ----------------------------------------------------------------------------------------
# glTF 2.0 binary (GLB) reader: just what a triangle-mesh scene needs.
# ----------------------------------------------------------------------------------------

GLB_MAGIC = 0x46546C67  # b"glTF"
CHUNK_JSON = 0x4E4F534A  # b"JSON"
CHUNK_BIN = 0x004E4942  # b"BIN\0"

COMPONENT_DTYPES = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
MODE_TRIANGLES = 4


class GltfError(ValueError):
    pass


def read_glb(path: str | os.PathLike) -> tuple[dict, bytes]:
    """Split a .glb file into its JSON document and its BIN chunk (b"" when absent)."""
    data = Path(path).read_bytes()
    if len(data) < 12:
        raise GltfError(f"{path}: too short for a GLB header")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC:
        raise GltfError(f"{path}: not a GLB file (magic {magic:#x})")
    if version != 2:
        raise GltfError(f"{path}: GLB version {version}, expected 2")
    if length > len(data):
        raise GltfError(f"{path}: header says {length} bytes, file has {len(data)}")
    doc, binary = None, b""
    offset = 12
    while offset + 8 <= length:
        chunk_len, chunk_type = struct.unpack_from("<II", data, offset)
        body = data[offset + 8 : offset + 8 + chunk_len]
        if len(body) != chunk_len:
            raise GltfError(f"{path}: truncated chunk at byte {offset}")
        if chunk_type == CHUNK_JSON and doc is None:
            doc = json.loads(body.decode("utf-8"))
        elif chunk_type == CHUNK_BIN and not binary:
            binary = body
        offset += 8 + chunk_len  # chunks are 4-byte aligned by the spec (padding included)
    if doc is None:
        raise GltfError(f"{path}: no JSON chunk")
    return doc, binary


def read_accessor(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor as a numpy array of shape (count,) or (count, components).

    Handles byteOffset on both the accessor and its bufferView, and interleaved data
    (byteStride). Sparse accessors and external buffers are not supported (the converted
    scenes use neither)."""
    acc = doc["accessors"][index]
    if "sparse" in acc:
        raise GltfError(f"accessor {index}: sparse accessors are not supported")
    dtype = np.dtype(COMPONENT_DTYPES[acc["componentType"]]).newbyteorder("<")
    ncomp = TYPE_COMPONENTS[acc["type"]]
    count = acc["count"]
    if "bufferView" not in acc:  # all zeros by the spec
        out = np.zeros((count, ncomp), dtype)
        return out[:, 0] if ncomp == 1 else out
    view = doc["bufferViews"][acc["bufferView"]]
    if view.get("buffer", 0) != 0 or "uri" in doc["buffers"][view.get("buffer", 0)]:
        raise GltfError(f"accessor {index}: only the GLB's own BIN chunk is supported")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    elem_size = dtype.itemsize * ncomp
    stride = view.get("byteStride") or elem_size
    if count == 0:
        out = np.zeros((0, ncomp), dtype)
    else:
        end = start + stride * (count - 1) + elem_size
        if end > view.get("byteOffset", 0) + view["byteLength"] or end > len(binary):
            raise GltfError(f"accessor {index}: reads past its bufferView or the BIN chunk")
        raw = np.frombuffer(binary, dtype=np.uint8, count=end - start, offset=start)
        if stride == elem_size:
            out = raw.view(dtype).reshape(count, ncomp)
        else:  # interleaved: take elem_size bytes out of every stride
            padded = np.zeros(stride * count, np.uint8)
            padded[: raw.size] = raw
            out = padded.reshape(count, stride)[:, :elem_size].copy().view(dtype)
        out = out.astype(dtype.newbyteorder("="), copy=True)
    return out[:, 0] if ncomp == 1 else out


def node_local_matrix(node: dict) -> np.ndarray:
    """4x4 (column vectors) local transform of a glTF node: `matrix` or T * R * S."""
    if "matrix" in node:
        return np.array(node["matrix"], np.float64).reshape(4, 4).T  # glTF is column-major
    t = np.array(node.get("translation", [0.0, 0.0, 0.0]), np.float64)
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    s = np.array(node.get("scale", [1.0, 1.0, 1.0]), np.float64)
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r * s[None, :]
    m[:3, 3] = t
    return m


@dataclass
class Material:
    """What the benchmark takes from a glTF material."""

    name: str
    base_color: tuple[float, float, float]
    radiance: tuple[float, float, float]  # emissiveFactor * emissive_strength
    double_sided: bool
    roughness: float
    metallic: float
    ior: float


@dataclass
class Primitive:
    """One triangle primitive in world space."""

    name: str
    positions: np.ndarray  # (V, 3) float32
    normals: np.ndarray | None  # (V, 3) float32, unit length
    indices: np.ndarray  # (F, 3) uint32, CCW = front face
    material: Material

    @property
    def emissive(self) -> bool:
        return max(self.material.radiance) > 0.0

    @property
    def triangle_count(self) -> int:
        return int(self.indices.shape[0])


@dataclass
class Camera:
    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    yfov_deg: float
    znear: float = 0.01


@dataclass
class Scene:
    path: Path
    primitives: list[Primitive]
    camera: Camera
    film: tuple[int, int]  # (width, height)
    extras: dict = field(default_factory=dict)

    @property
    def triangle_count(self) -> int:
        return sum(p.triangle_count for p in self.primitives)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        pts = np.concatenate([p.positions for p in self.primitives])
        return pts.min(axis=0), pts.max(axis=0)


def _material(doc: dict, index: int | None) -> Material:
    if index is None:  # glTF default material: white, not emissive, one-sided, metallic 1
        return Material("default", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), False, 1.0, 1.0, 1.5)
    mat = doc["materials"][index]
    pbr = mat.get("pbrMetallicRoughness", {})
    base = tuple(float(c) for c in pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3])
    strength = float(
        mat.get("extensions", {})
        .get("KHR_materials_emissive_strength", {})
        .get("emissiveStrength", 1.0)
    )
    radiance = tuple(float(c) * strength for c in mat.get("emissiveFactor", [0.0, 0.0, 0.0]))
    return Material(
        name=mat.get("name", f"material{index}"),
        base_color=base,
        radiance=radiance,
        double_sided=bool(mat.get("doubleSided", False)),
        roughness=float(pbr.get("roughnessFactor", 1.0)),
        metallic=float(pbr.get("metallicFactor", 1.0)),
        ior=float(mat.get("extensions", {}).get("KHR_materials_ior", {}).get("ior", 1.5)),
    )


def load_gltf_primitives(glb_path: str | os.PathLike) -> list[Primitive]:
    """All triangle primitives of the GLB's default scene, transformed to world space."""
    doc, binary = read_glb(glb_path)
    scene_index = doc.get("scene", 0)
    roots = doc["scenes"][scene_index]["nodes"] if doc.get("scenes") else range(len(doc["nodes"]))
    prims: list[Primitive] = []
    stack = [(n, np.eye(4)) for n in roots]
    while stack:
        node_index, parent = stack.pop(0)
        node = doc["nodes"][node_index]
        world = parent @ node_local_matrix(node)
        for child in node.get("children", []):
            stack.append((child, world))
        if "mesh" not in node:
            continue
        mesh = doc["meshes"][node["mesh"]]
        lin = world[:3, :3]
        normal_matrix = np.linalg.inv(lin).T
        flip = np.linalg.det(lin) < 0.0  # a mirroring transform reverses the winding
        for k, prim in enumerate(mesh["primitives"]):
            if prim.get("mode", MODE_TRIANGLES) != MODE_TRIANGLES:
                raise GltfError(f"mesh {mesh.get('name')} primitive {k}: only triangle lists")
            attrs = prim["attributes"]
            pos = read_accessor(doc, binary, attrs["POSITION"]).astype(np.float64)
            pos = pos @ lin.T + world[:3, 3]
            nrm = None
            if "NORMAL" in attrs:
                nrm = read_accessor(doc, binary, attrs["NORMAL"]).astype(np.float64) @ normal_matrix.T
                length = np.linalg.norm(nrm, axis=1, keepdims=True)
                nrm = nrm / np.where(length > 0.0, length, 1.0)
            if "indices" in prim:
                idx = read_accessor(doc, binary, prim["indices"]).astype(np.uint32)
            else:
                idx = np.arange(pos.shape[0], dtype=np.uint32)
            if idx.size % 3:
                raise GltfError(f"primitive {k}: {idx.size} indices is not a multiple of 3")
            if idx.size and int(idx.max()) >= pos.shape[0]:
                raise GltfError(f"primitive {k}: index {int(idx.max())} out of range")
            idx = idx.reshape(-1, 3)
            if flip:
                idx = idx[:, [0, 2, 1]]
            mat = _material(doc, prim.get("material"))
            name = f"{node.get('name', 'node%d' % node_index)}_{k}_{mat.name}"
            prims.append(
                Primitive(
                    name=re.sub(r"[^A-Za-z0-9_]", "_", name),
                    positions=np.ascontiguousarray(pos, np.float32),
                    normals=None if nrm is None else np.ascontiguousarray(nrm, np.float32),
                    indices=np.ascontiguousarray(idx, np.uint32),
                    material=mat,
                )
            )
    return prims


def load_scene(scene_dir: str | os.PathLike) -> Scene:
    """Read a shared/scenes folder: scene.json (camera, film) and the glTF it names."""
    scene_dir = Path(scene_dir)
    meta = json.loads((scene_dir / "scene.json").read_text())
    gltf_name = meta.get("gltf", "scene.glb")
    if not gltf_name.lower().endswith(".glb"):
        raise GltfError(f"{gltf_name}: only binary glTF (.glb) is supported by this loader")
    if meta.get("environment"):
        raise GltfError("scenes with an environment map are not supported by this benchmark")
    cam = meta["camera"]
    camera = Camera(
        position=tuple(float(v) for v in cam["position"]),
        target=tuple(float(v) for v in cam["target"]),
        up=tuple(float(v) for v in cam["up"]),
        yfov_deg=float(cam["yfov_deg"]),
        znear=float(cam.get("znear", 0.01)),
    )
    film = tuple(int(v) for v in meta.get("film", [256, 256]))
    prims = load_gltf_primitives(scene_dir / gltf_name)
    return Scene(path=scene_dir, primitives=prims, camera=camera, film=film, extras=meta)


# ----------------------------------------------------------------------------------------
# libLLVM discovery (for Dr.Jit's LLVM backend)
# ----------------------------------------------------------------------------------------

LLVM_GLOBS = (
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
)


def llvm_major_from_path(path: str) -> int | None:
    """Major version from a libLLVM file name: libLLVM-19.so, libLLVM.so.19.1,
    libLLVM-15.so.1, /usr/lib/llvm-16/lib/libLLVM-16.so, libLLVM-14.0.6.so.1."""
    name = os.path.basename(path)
    m = re.match(r"libLLVM-(\d+)", name) or re.match(r"libLLVM\.so\.(\d+)", name)
    if not m:
        m = re.search(r"/llvm-(\d+)/", path)
    return int(m.group(1)) if m else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> tuple[str | None, int | None]:
    """(path, major) of the newest libLLVM found, DRJIT_LIBLLVM_PATH first when set."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env, llvm_major_from_path(os.path.realpath(env)) or llvm_major_from_path(env)
    best: tuple[int, str] | None = None
    for pattern in LLVM_GLOBS:
        for cand in sorted(glob.glob(pattern)):
            if not os.path.isfile(cand):
                continue
            major = llvm_major_from_path(cand) or llvm_major_from_path(os.path.realpath(cand))
            if major is None or major < min_major:
                continue
            if best is None or major > best[0]:
                best = (major, cand)
    return (best[1], best[0]) if best else (None, None)


# ----------------------------------------------------------------------------------------
# Mitsuba scene and benchmark
# ----------------------------------------------------------------------------------------


def setup_mitsuba(variant: str, threads: int | None):
    """Import mitsuba with the requested variant; returns (mi, dr, llvm_path)."""
    llvm_path = None
    if variant.startswith("llvm"):
        llvm_path, _ = find_libllvm()
        if llvm_path is None:
            raise SystemExit("bench_mitsuba: " + LLVM_INSTALL_HINT)
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm_path  # read when the LLVM backend starts
    import drjit as dr
    import mitsuba as mi

    if threads is not None:
        dr.set_thread_count(int(threads))
    if variant not in mi.variants():
        raise SystemExit(f"bench_mitsuba: variant {variant} is not in this build: {mi.variants()}")
    mi.set_variant(variant)
    if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        raise SystemExit(f"bench_mitsuba: Dr.Jit could not start LLVM from {llvm_path}. " + LLVM_INSTALL_HINT)
    return mi, dr, llvm_path


def _rgb(value) -> dict:
    return {"type": "rgb", "value": [float(v) for v in value]}


def build_mitsuba_dict(
    scene: Scene,
    width: int,
    height: int,
    spp: int,
    max_depth: int,
    rr_depth: int,
    bsdf: str = "diffuse",
) -> dict:
    """The mi.load_dict description (mitsuba must be imported, variant set); `bsdf` as
    bsdf_dict."""
    import mitsuba as mi

    cam = scene.camera
    desc: dict = {
        "type": "scene",
        "integrator": {
            "type": "path",
            "max_depth": int(max_depth),
            "rr_depth": int(rr_depth),
            "hide_emitters": False,
        },
        "sensor": {
            "type": "perspective",
            "fov_axis": "y",
            "fov": cam.yfov_deg,
            "near_clip": cam.znear,
            "far_clip": 1.0e7,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(cam.position), target=list(cam.target), up=list(cam.up)
            ),
            "film": {
                "type": "hdrfilm",
                "width": int(width),
                "height": int(height),
                "pixel_format": "rgb",
                "rfilter": {"type": "box"},
            },
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },
    }
    for k, prim in enumerate(scene.primitives):
        desc[f"mesh_{k}_{prim.name}"] = make_mesh(prim, bsdf)
    return desc


BSDFS = ("diffuse", "principled")
"""`diffuse`: Mitsuba's own Cornell box's BSDF. `principled`: the glTF material's counterpart."""


def specular_level(ior: float) -> float:
    """Mitsuba `principled`'s `specular` for a dielectric of index `ior`: its normal-incidence
    reflectance ((ior - 1) / (ior + 1))^2 over 0.08 (0.5 for 1.5, reflectance 0.04)."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2 / 0.08


def bsdf_dict(m: Material, kind: str = "diffuse") -> dict:
    """The Mitsuba BSDF description of a material (no mitsuba import needed)."""
    if kind == "diffuse":
        bsdf = {"type": "diffuse", "reflectance": _rgb(m.base_color)}
    elif kind == "principled":
        bsdf = {
            "type": "principled",
            "base_color": _rgb(m.base_color),
            "roughness": float(m.roughness),
            "metallic": float(m.metallic),
            "specular": specular_level(m.ior),
        }
    else:
        raise ValueError(f"bsdf must be one of {BSDFS}, got {kind!r}")
    if m.double_sided:
        bsdf = {"type": "twosided", "material": bsdf}
    return bsdf


def make_mesh(prim: Primitive, bsdf: str = "diffuse"):
    """A mitsuba Mesh filled from the primitive's arrays, with its BSDF and emitter."""
    import mitsuba as mi

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf_dict(prim.material, bsdf))
    if prim.emissive:
        props["emitter"] = mi.load_dict({"type": "area", "radiance": _rgb(prim.material.radiance)})
    has_normals = prim.normals is not None
    mesh = mi.Mesh(
        prim.name,
        vertex_count=int(prim.positions.shape[0]),
        face_count=int(prim.indices.shape[0]),
        props=props,
        has_vertex_normals=has_normals,
        has_vertex_texcoords=False,
    )
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(prim.positions, np.float32).ravel()
    params["faces"] = np.ascontiguousarray(prim.indices, np.uint32).ravel()
    if has_normals:
        params["vertex_normals"] = np.ascontiguousarray(prim.normals, np.float32).ravel()
    params.update()
    return mesh


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cpu_flags() -> list[str]:
    """The SIMD extensions that matter for a vectorising JIT (from /proc/cpuinfo)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                wanted = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl")
                return [f for f in wanted if f in flags]
    except OSError:
        pass
    return []


def _cpu_seconds() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def run_benchmark(
    scene_dir: str | os.PathLike = DEFAULT_SCENE,
    width: int | None = None,
    height: int | None = None,
    spp: int = 64,
    max_depth: int = 8,
    rr_depth: int = 3,
    repeats: int = 3,
    threads: int | None = None,
    variant: str = "llvm_ad_rgb",
    out: str | None = None,
    bsdf: str = "diffuse",
) -> dict:
    """Render untimed once, then `repeats` timed renders; returns the result record."""
    if repeats < 1:
        raise ValueError("repeats must be >= 1")
    scene = load_scene(scene_dir)
    width = int(width or scene.film[0])
    height = int(height or scene.film[1])
    mi, dr, llvm_path = setup_mitsuba(variant, threads)
    jit = variant.startswith(("llvm", "cuda"))

    t0 = time.perf_counter()
    mi_scene = mi.load_dict(build_mitsuba_dict(scene, width, height, spp, max_depth, rr_depth, bsdf))
    load_s = time.perf_counter() - t0

    def render(seed: int):
        img = mi.render(mi_scene, seed=seed, spp=spp)
        if jit:
            dr.eval(img)
            dr.sync_thread()
        return img

    loadavg_before = os.getloadavg()
    t0 = time.perf_counter()
    img = render(0)  # untimed: JIT compilation and kernel caching
    warmup_s = time.perf_counter() - t0

    if jit:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
    times, cpu_times, compiled, kernel_ms = [], [], [], []
    for seed in range(1, repeats + 1):
        if jit:
            dr.kernel_history_clear()
        c0 = _cpu_seconds()
        t0 = time.perf_counter()
        img = render(seed)
        times.append(time.perf_counter() - t0)
        cpu_times.append(_cpu_seconds() - c0)
        if jit:
            hist = [h for h in dr.kernel_history() if h.get("type") == dr.KernelType.JIT]
            compiled.append(sum(1 for h in hist if not h.get("cache_hit", 0)))
            kernel_ms.append(sum(h.get("execution_time", 0.0) for h in hist))
    if jit:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    loadavg_after = os.getloadavg()

    pixels = np.array(img, dtype=np.float64)
    mean = pixels.reshape(-1, pixels.shape[-1])[:, :3].mean(axis=0)
    threads_used = dr.thread_count()
    if out:
        # Mitsuba 3.9.1 deadlocks writing an EXR when Dr.Jit's pool has a single thread
        # (OpenEXR's work goes through that pool): widen it just for the write.
        if threads_used < 2:
            dr.set_thread_count(2)
        mi.util.write_bitmap(str(out), img, write_async=False)
        dr.set_thread_count(threads_used)

    median = statistics.median(times)
    utilisation = statistics.median(c / t for c, t in zip(cpu_times, times))
    llvm_version = None
    if jit and variant.startswith("llvm"):
        try:
            llvm_version = ".".join(str(v) for v in dr.detail.llvm_version())
        except Exception:  # pragma: no cover - API differences across drjit versions
            llvm_version = None
    return {
        "renderer": "mitsuba3",
        "variant": variant,
        "scene": str(Path(scene_dir).resolve()),
        "triangles": scene.triangle_count,
        "width": width,
        "height": height,
        "spp": spp,
        "max_depth": max_depth,
        "rr_depth": rr_depth,
        "integrator": "path (NEE + MIS), hide_emitters=false; "
        + bsdf
        + " BSDFs; box filter; independent sampler",
        "bsdf": bsdf,
        "paths_per_render": width * height * spp,
        "repeats": repeats,
        "times_s": [round(t, 4) for t in times],
        "median_s": round(median, 4),
        "paths_per_s": width * height * spp / median,
        "cpu_time_s": [round(t, 4) for t in cpu_times],
        "cpu_utilisation": round(utilisation, 3),
        # The render threads got well under their cores: other processes were running, so
        # paths/s understates Mitsuba's speed on an idle machine. Re-run when it is idle.
        "contended": bool(jit and utilisation < 0.9 * min(threads_used, os.cpu_count() or 1)),
        "kernels_compiled_in_timed_runs": compiled if jit else None,
        "jit_kernel_ms": [round(t, 1) for t in kernel_ms] if jit else None,
        "warmup_s": round(warmup_s, 3),
        "scene_load_s": round(load_s, 3),
        "threads": threads_used,
        "logical_cpus": os.cpu_count(),
        "cpu_model": cpu_model(),
        "cpu_simd": cpu_flags(),
        "loadavg_before": [round(v, 2) for v in loadavg_before],
        "loadavg_after": [round(v, 2) for v in loadavg_after],
        "mitsuba_version": mi.__version__,
        "drjit_version": dr.__version__,
        "llvm_library": llvm_path,
        "llvm_version": llvm_version,
        "python": platform.python_version(),
        "image_mean_rgb": [round(float(v), 5) for v in mean],
        "image_out": str(out) if out else None,
    }


def format_report(r: dict) -> str:
    lines = [
        f"Mitsuba {r['mitsuba_version']} (drjit {r['drjit_version']}), variant {r['variant']}",
        f"  LLVM: {r['llvm_library']} ({r['llvm_version']})" if r["llvm_library"] else "  LLVM: not used",
        f"  scene {r['scene']}: {r['triangles']} triangles",
        f"  {r['width']}x{r['height']}, {r['spp']} spp, max_depth {r['max_depth']}, "
        f"rr_depth {r['rr_depth']} (Mitsuba's default is 5), {r['integrator']}",
        f"  CPU: {r['cpu_model']} ({r['logical_cpus']} logical CPUs, SIMD {','.join(r['cpu_simd'])}), "
        f"{r['threads']} render threads",
        f"  warm-up render (untimed, includes JIT): {r['warmup_s']:.3f} s",
        f"  timed renders: {', '.join('%.3f' % t for t in r['times_s'])} s "
        f"(kernels compiled during them: {r['kernels_compiled_in_timed_runs']})",
        f"  median {r['median_s']:.3f} s -> {r['paths_per_s']:.4g} paths/s "
        f"({r['paths_per_render']} paths per render), CPU utilisation {r['cpu_utilisation']:.2f} cores",
        f"  load average before/after: {r['loadavg_before']} / {r['loadavg_after']}",
        f"  image mean RGB: {r['image_mean_rgb']}",
    ]
    if r.get("contended"):
        lines.append(
            "  WARNING: the render used %.2f of %d cores: the machine was busy, so this "
            "understates the idle speed; re-run on an idle machine" % (r["cpu_utilisation"], r["threads"])
        )
    if r.get("image_out"):
        lines.append(f"  wrote {r['image_out']}")
    return "\n".join(lines)


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(DEFAULT_SCENE), help="a shared/scenes folder (scene.json + .glb)")
    ap.add_argument("--width", type=int, default=None, help="film width (default: scene.json)")
    ap.add_argument("--height", type=int, default=None, help="film height (default: scene.json)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=8, help="path segments; 1 = emitters seen directly")
    ap.add_argument("--rr-depth", type=int, default=3, help="segment at which Russian roulette starts (Mitsuba's default: 5)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="Dr.Jit worker threads (default: all cores)")
    ap.add_argument("--variant", default="llvm_ad_rgb", help="llvm_ad_rgb (default) or scalar_rgb")
    ap.add_argument("--out", default=None, help="write the last timed render (.exr, .png, ...)")
    ap.add_argument("--bsdf", default="diffuse", choices=BSDFS,
                    help="diffuse (Mitsuba's own Cornell box) or principled (the glTF metallic-roughness material's counterpart)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    result = run_benchmark(
        scene_dir=args.scene,
        width=args.width,
        height=args.height,
        spp=args.spp,
        max_depth=args.max_depth,
        rr_depth=args.rr_depth,
        repeats=args.repeats,
        threads=args.threads,
        variant=args.variant,
        out=args.out,
        bsdf=args.bsdf,
    )
    result["command"] = " ".join([os.path.basename(sys.executable), *sys.argv])
    if result["contended"]:
        print(
            "bench_mitsuba: warning: CPU utilisation %.2f with %d threads: the machine was busy"
            % (result["cpu_utilisation"], result["threads"]),
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps(result))
    else:
        print(format_report(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
