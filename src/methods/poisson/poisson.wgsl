// poisson on the GPU: the passes of methods/poisson/mod.rs, one entry point per pass, each
// computing what its CPU twin computes, in f32 (gpu/common.wgsl and poisson/gather.wgsl are
// prepended).
//
// 1. coc:    depth -> signed CoC radius in pixels (ThinLens::coc_px), clamped to
//            +-max_coc_px; the first pixel (row order) whose depth is not > 0 is recorded in
//            status[0].
// 2. gather: colour, CoC -> out: each pixel's Poisson-disc taps scaled by its CoC, with depth
//            rejection (gather_at); with a cat's eye each pixel keeps the taps that pass its
//            view of the lens barrel.
// Storage buffers of one value a pixel, row-major.

struct Params {
    width: u32,
    height: u32,
    tap_count: u32,
    // 1 with a cat's eye.
    cats_eye: u32,
    f_times_e: f32,
    focus_m: f32,
    max_coc_px: f32,
    // The barrel's radius in aperture radii (LensEffects::barrel).
    barrel_radius: f32,
    // The image centre in pixels, and the barrel's shift per pixel from it, in aperture radii.
    centre: vec2<f32>,
    shift_per_px: f32,
    pad: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> depth_bits: array<u32>;
@group(0) @binding(2) var<storage, read_write> coc_px: array<f32>;
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read> color: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> taps: array<vec4<f32>>;

@compute @workgroup_size(64, 1, 1)
fn coc(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.width || id.y >= params.height) {
        return;
    }
    let i = id.y * params.width + id.x;
    let bits = depth_bits[i];
    if (depth_is_bad(bits)) {
        atomicMin(&status[0], i);
        coc_px[i] = 0.0;
        return;
    }
    coc_px[i] = coc_of_depth(bits, params.f_times_e, params.focus_m, params.max_coc_px);
}

@compute @workgroup_size(64, 1, 1)
fn gather(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.width || id.y >= params.height) {
        return;
    }
    var shift = vec2<f32>(0.0);
    var radius2 = 3.4028235e38;
    if (params.cats_eye != 0u) {
        let p = vec2<f32>(f32(id.x) + 0.5, f32(id.y) + 0.5);
        shift = (p - params.centre) * params.shift_per_px;
        radius2 = params.barrel_radius * params.barrel_radius;
    }
    out[id.y * params.width + id.x] = gather_at(id.x, id.y, shift, radius2);
}
