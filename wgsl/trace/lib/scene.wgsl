// The scene every tracer kernel reads (render::GpuScene, layouts in common.wgsl and
// lights.wgsl), declared once: bindings 1-7 of group 0 in every kernel that includes this
// file; each kernel's own resources start at binding 8. A kernel's layout holds only the
// arrays it reaches (the registry leaves the others out of its bind group).

@group(0) @binding(1) var<storage, read> bvh_nodes: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> tris: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> verts: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> materials: array<Material>;
@group(0) @binding(5) var<storage, read> texels: array<u32>;
@group(0) @binding(6) var<storage, read> lights: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> env: array<vec4<f32>>;
