// gaussian on the GPU: the passes of methods/gaussian/mod.rs, one entry point per pass, each
// computing what its CPU twin computes, in f32 and in the same order of summation
// (gpu/common.wgsl is prepended).
//
// 1. coc:        depth -> signed CoC radius in pixels (ThinLens::coc_px), clamped to
//                +-max_coc_px; the first pixel (row order) whose depth is not > 0 is recorded
//                in status[0].
// 2. horizontal: colour, CoC -> rows: each pixel gathers its row with the Gaussian of its
//                quantised radius times the depth-rejection weight (poisson::rejection_weight).
// 3. vertical:   rows, CoC -> out: the same along columns; pixels of radius <= 1/2 px keep the
//                colour.
// Storage buffers of one value a pixel, row-major; depth as the bits of its f32, so +inf (the
// sky) and NaN are read without the shader relying on IEEE special values.

struct Params {
    width: u32,
    height: u32,
    // Table row length: the largest half width + 1.
    stride: u32,
    // Quantised radius levels of the table.
    levels: u32,
    // f_px * lens_radius_m, as the CPU's coc_px multiplies them.
    f_times_e: f32,
    focus_m: f32,
    max_coc_px: f32,
    pad: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> depth_bits: array<u32>;
@group(0) @binding(2) var<storage, read_write> coc_px: array<f32>;
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read> color: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> rows: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> half_taps: array<u32>;
@group(0) @binding(8) var<storage, read> weights: array<f32>;

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

fn level_of(c: f32) -> u32 {
    return level_in(c, params.levels);
}

@compute @workgroup_size(64, 1, 1)
fn horizontal(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.width;
    if (id.x >= w || id.y >= params.height) {
        return;
    }
    let x = id.x;
    let row = id.y * w;
    let c = coc_px[row + x];
    let level = level_of(c);
    let n = half_taps[level];
    if (n == 0u) {
        rows[row + x] = color[row + x];
        return;
    }
    let base = level * params.stride;
    var acc = vec4<f32>(0.0);
    var total = 0.0;
    // As the CPU: the taps inside the row first, then those beyond each border, which repeat
    // the edge pixel.
    var lo = 0u;
    if (x > n) {
        lo = x - n;
    }
    let hi = min(x + n, w - 1u);
    for (var q = lo; q <= hi; q++) {
        let d = max(q, x) - min(q, x);
        let wt = weights[base + d] * rejection_weight(c, coc_px[row + q]);
        acc += wt * color[row + q];
        total += wt;
    }
    for (var d = x + 1u; d <= n; d++) {
        let wt = weights[base + d] * rejection_weight(c, coc_px[row]);
        acc += wt * color[row];
        total += wt;
    }
    for (var d = w - x; d <= n; d++) {
        let wt = weights[base + d] * rejection_weight(c, coc_px[row + w - 1u]);
        acc += wt * color[row + w - 1u];
        total += wt;
    }
    rows[row + x] = acc / total;
}

@compute @workgroup_size(64, 1, 1)
fn vertical(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.width;
    let h = params.height;
    if (id.x >= w || id.y >= h) {
        return;
    }
    let i = id.y * w + id.x;
    let c = coc_px[i];
    let level = level_of(c);
    let n = i32(half_taps[level]);
    if (n == 0) {
        out[i] = color[i];
        return;
    }
    let base = level * params.stride;
    var acc = vec4<f32>(0.0);
    var total = 0.0;
    // d from -n to n, as the CPU; rows beyond the borders repeat the edge row.
    for (var d = -n; d <= n; d++) {
        let yy = u32(clamp(i32(id.y) - d, 0, i32(h) - 1));
        let j = yy * w + id.x;
        let wt = weights[base + u32(abs(d))] * rejection_weight(c, coc_px[j]);
        acc += wt * rows[j];
        total += wt;
    }
    out[i] = acc / total;
}
