// lowrank on the GPU: the passes of methods/lowrank/ (depth of field, fig. 15), one entry point
// per pass, each computing what its CPU twin computes, in f32 (gpu/common.wgsl and
// poisson/gather.wgsl are prepended).
//
// 1. coc:        depth -> signed CoC radius in pixels, clamped to +-max_coc_px; the first pixel
//                whose depth is not > 0 in status[0], the largest |C| in status[1] (the bits
//                of a positive f32 order as the floats do), 1 in status[2] if any alpha is not
//                1. The CPU reads these back to build the kernel bank (dof::KernelBank).
// 2. edges:      CoC -> 1 where it differs from a 4-neighbour's by more than the threshold.
// 3. horizontal: for rank i, colour and edges -> inter: each pixel's own horizontal taps
//                (table key sign * levels + level), clamp-to-edge.
// 4. vertical:   for rank i, inter -> out (+= for ranks after the first): each pixel's own
//                vertical taps; after the last rank the final touch of dof::filter: pixels
//                without taps beyond their own get their colour back, the others are clamped
//                to 0 from below (alpha 1 for an opaque frame).
// 5. fallback:   where the filtered edge image exceeds mask_threshold and |C| > 1/2, the
//                Poisson-disc gather with depth rejection (gather_at) replaces the pixel.
// Storage buffers of one value a pixel, row-major; tap tables as dof::KernelBank lays them
// out: [(key * rank + i) * stride + j], tap j reading the pixel at offset j - nmax.

struct Params {
    width: u32,
    height: u32,
    rank: u32,
    rank_index: u32,
    levels: u32,
    nmax: u32,
    stride: u32,
    // 1 for the last rank's vertical pass.
    last: u32,
    // 1 with the depth-discontinuity mask.
    use_edges: u32,
    // 1 when every alpha of the colour is 1.
    opaque: u32,
    tap_count: u32,
    pad0: u32,
    f_times_e: f32,
    focus_m: f32,
    max_coc_px: f32,
    edge_threshold_px: f32,
    mask_threshold: f32,
    pad1: f32,
    pad2: f32,
    pad3: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> depth_bits: array<u32>;
@group(0) @binding(2) var<storage, read_write> coc_px: array<f32>;
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read> color: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> edge_map: array<f32>;
@group(0) @binding(6) var<storage, read_write> inter: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> inter_edge: array<f32>;
@group(0) @binding(8) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> out_edge: array<f32>;
@group(0) @binding(10) var<storage, read> h_taps: array<f32>;
@group(0) @binding(11) var<storage, read> v_taps: array<f32>;
// The half widths of every key: horizontal (2 levels entries), then vertical.
@group(0) @binding(12) var<storage, read> half_taps: array<u32>;
@group(0) @binding(13) var<storage, read> taps: array<vec4<f32>>;

// KernelBank::key: the far field's levels, then the near field's.
fn key_of(c: f32) -> u32 {
    var key = level_in(c, params.levels);
    if (c < 0.0) {
        key += params.levels;
    }
    return key;
}

@compute @workgroup_size(64, 1, 1)
fn coc(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.width || id.y >= params.height) {
        return;
    }
    let i = id.y * params.width + id.x;
    if (color[i].a != 1.0) {
        atomicOr(&status[2], 1u);
    }
    let bits = depth_bits[i];
    if (depth_is_bad(bits)) {
        atomicMin(&status[0], i);
        coc_px[i] = 0.0;
        return;
    }
    let c = coc_of_depth(bits, params.f_times_e, params.focus_m, params.max_coc_px);
    coc_px[i] = c;
    atomicMax(&status[1], bitcast<u32>(abs(c)));
}

@compute @workgroup_size(64, 1, 1)
fn edges(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.width;
    let h = params.height;
    if (id.x >= w || id.y >= h) {
        return;
    }
    let i = id.y * w + id.x;
    let c = coc_px[i];
    // A missing neighbour is the pixel itself: a difference of 0.
    let up = coc_px[max(id.y, 1u) * w - w + id.x];
    let down = coc_px[min(id.y + 1u, h - 1u) * w + id.x];
    let left = coc_px[i - select(0u, 1u, id.x > 0u)];
    let right = coc_px[i + select(0u, 1u, id.x + 1u < w)];
    let e = max(max(abs(c - up), abs(c - down)), max(abs(c - left), abs(c - right)));
    edge_map[i] = select(0.0, 1.0, e > params.edge_threshold_px);
}

@compute @workgroup_size(64, 1, 1)
fn horizontal(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.width;
    if (id.x >= w || id.y >= params.height) {
        return;
    }
    let row = id.y * w;
    let i = row + id.x;
    let key = key_of(coc_px[i]);
    let n = half_taps[key];
    let base = (key * params.rank + params.rank_index) * params.stride;
    var acc = vec4<f32>(0.0);
    var acc_edge = 0.0;
    for (var j = params.nmax - n; j <= params.nmax + n; j++) {
        let wt = h_taps[base + j];
        if (wt != 0.0) {
            let sx = u32(clamp(i32(id.x + j) - i32(params.nmax), 0, i32(w) - 1));
            acc += wt * color[row + sx];
            if (params.use_edges != 0u) {
                acc_edge += wt * edge_map[row + sx];
            }
        }
    }
    inter[i] = acc;
    inter_edge[i] = acc_edge;
}

@compute @workgroup_size(64, 1, 1)
fn vertical(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.width;
    let h = params.height;
    if (id.x >= w || id.y >= h) {
        return;
    }
    let i = id.y * w + id.x;
    let key = key_of(coc_px[i]);
    let n = half_taps[2u * params.levels + key];
    let base = (key * params.rank + params.rank_index) * params.stride;
    var acc = vec4<f32>(0.0);
    var acc_edge = 0.0;
    if (params.rank_index > 0u) {
        acc = out[i];
        acc_edge = out_edge[i];
    }
    for (var j = params.nmax - n; j <= params.nmax + n; j++) {
        let wt = v_taps[base + j];
        if (wt != 0.0) {
            let sy = u32(clamp(i32(id.y + j) - i32(params.nmax), 0, i32(h) - 1));
            acc += wt * inter[sy * w + id.x];
            acc_edge += wt * inter_edge[sy * w + id.x];
        }
    }
    out_edge[i] = acc_edge;
    if (params.last == 0u) {
        out[i] = acc;
    } else if (half_taps[key] == 0u && n == 0u) {
        out[i] = color[i];
    } else {
        var alpha = max(acc.a, 0.0);
        if (params.opaque != 0u) {
            alpha = 1.0;
        }
        out[i] = vec4<f32>(max(acc.rgb, vec3<f32>(0.0)), alpha);
    }
}

@compute @workgroup_size(64, 1, 1)
fn fallback(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.width || id.y >= params.height) {
        return;
    }
    let i = id.y * params.width + id.x;
    if (out_edge[i] > params.mask_threshold && abs(coc_px[i]) > 0.5) {
        out[i] = gather_at(id.x, id.y, vec2<f32>(0.0), 3.4028235e38);
    }
}
