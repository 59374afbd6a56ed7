// hammon on the GPU: the passes of methods/hammon/, one entry point per pass (the blur in two,
// its columns then its rows), each computing what its CPU twin computes, in f32.
//
// 1. downsample:  colour, depth -> shrunk: the mean RGBA of each 4x4 block (a partial block at
//                 the right or bottom averages the pixels it has) and the largest near blur
//                 amount of its pixels; a depth that is not > 0 sets status[0].
// 2. blur:        shrunk -> large: the truncated Gaussian `kernel` over quarter-res texels,
//                 down the columns (blur_vertical, into tmp) then along the rows
//                 (blur_horizontal), colour and near blur together, edges clamped.
// 3. near_coc:    shrunk, large -> medium: D = saturate(2 max(DB, D0) - D0), then the 3x3
//                 [1 2 1]^2 / 16 blur of (shrunk colour, D), as four 2x2 means of 2x2 means.
// 4. composite:   colour, depth, medium, large -> out: the small blur (four bilinear taps of
//                 fig. 28-5), medium and large sampled bilinearly, t = max(near, far), and the
//                 blend of Listing 28-4 with dofLerpScale / dofLerpBias.
// The signed blur amount s of a pixel (coc.rs) is computed from depth where a pass reads it,
// as the CPU does. Depth is read as the bits of its f32, so +inf (the sky) is found without
// the shader relying on IEEE special values.

struct Params {
    width: u32,
    height: u32,
    qw: u32,
    qh: u32,
    // 0: the thin lens (CocMode::Physical); 1: the artist curve.
    mode: u32,
    // Half width of the large Gaussian, in quarter-res texels.
    radius: u32,
    // 1 when sky_depth_m is +inf: no pixel is sky.
    sky_is_inf: u32,
    pad0: u32,
    // f_px * lens_radius_m, as the CPU's coc_px multiplies them.
    f_times_e: f32,
    focus_m: f32,
    inv_large_blur_coc_px: f32,
    far_to_near_ratio: f32,
    near_scale: f32,
    near_bias: f32,
    far_scale: f32,
    far_bias: f32,
    sky_depth_m: f32,
    pad1: f32,
    pad2: f32,
    pad3: f32,
    lerp_scale: vec4<f32>,
    lerp_bias: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> depth_bits: array<u32>;
@group(0) @binding(2) var<storage, read> color: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> shrunk_color: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> shrunk_coc: array<f32>;
@group(0) @binding(6) var<storage, read_write> tmp_color: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> tmp_coc: array<f32>;
@group(0) @binding(8) var<storage, read_write> large_color: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> large_coc: array<f32>;
@group(0) @binding(10) var<storage, read_write> medium_color: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> medium_coc: array<f32>;
@group(0) @binding(12) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read> kernel: array<f32>;

const INF_BITS: u32 = 0x7f800000u;
const ABS_MASK: u32 = 0x7fffffffu;

// mod.rs `saturate`: clamped to [0, 1] (NaN does not reach it here).
fn saturate1(x: f32) -> f32 {
    return clamp(x, 0.0, 1.0);
}

// coc.rs: the signed blur amount of depth bits that are valid (> 0, or +inf).
fn amount(bits: u32) -> f32 {
    let z_inf = bits == INF_BITS;
    let z = bitcast<f32>(bits);
    var near: f32;
    var far: f32;
    if (params.mode == 0u) {
        // ThinLens::coc_px: f E (z - z_f) / (z_f z); 1 / z_f where z_f z overflows.
        var ratio: f32;
        if (z_inf) {
            ratio = 1.0 / params.focus_m;
        } else {
            let den = params.focus_m * z;
            if ((bitcast<u32>(den) & ABS_MASK) == INF_BITS) {
                ratio = 1.0 / params.focus_m;
            } else {
                ratio = (z - params.focus_m) / den;
            }
        }
        let t = params.f_times_e * ratio * params.inv_large_blur_coc_px;
        near = -t;
        far = t;
    } else if (z_inf) {
        // The CPU's scale * inf + bias: -inf or NaN for the near side (saturated to 0), +inf
        // (1) or NaN (0) for the far side.
        near = 0.0;
        far = select(0.0, 1.0, params.far_scale > 0.0);
    } else {
        near = params.near_scale * z + params.near_bias;
        far = params.far_scale * z + params.far_bias;
    }
    var sky = false;
    if (params.sky_is_inf == 0u) {
        sky = z_inf || z > params.sky_depth_m;
    }
    var far_amount = 0.0;
    if (!sky) {
        far_amount = saturate1(saturate1(far) * params.far_to_near_ratio);
    }
    return far_amount - saturate1(near);
}

@compute @workgroup_size(8, 8, 1)
fn downsample(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.qw || id.y >= params.qh) {
        return;
    }
    let w = params.width;
    let x0 = 4u * id.x;
    let y0 = 4u * id.y;
    let x1 = min(x0 + 4u, w);
    let y1 = min(y0 + 4u, params.height);
    var sum = vec4<f32>(0.0);
    var near_max = 0.0;
    for (var y = y0; y < y1; y++) {
        for (var x = x0; x < x1; x++) {
            let i = y * w + x;
            let bits = depth_bits[i];
            if (bits == 0u || bits > INF_BITS) {
                atomicMin(&status[0], i);
                continue;
            }
            sum += color[i];
            near_max = max(near_max, -amount(bits));
        }
    }
    let q = id.y * params.qw + id.x;
    shrunk_color[q] = sum * (1.0 / f32((y1 - y0) * (x1 - x0)));
    shrunk_coc[q] = near_max;
}

@compute @workgroup_size(64, 1, 1)
fn blur_vertical(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.qw || id.y >= params.qh) {
        return;
    }
    let r = i32(params.radius);
    var c = vec4<f32>(0.0);
    var k = 0.0;
    for (var i = 0; i <= 2 * r; i++) {
        let y = u32(clamp(i32(id.y) + i - r, 0, i32(params.qh) - 1));
        let j = y * params.qw + id.x;
        c += kernel[i] * shrunk_color[j];
        k += kernel[i] * shrunk_coc[j];
    }
    let q = id.y * params.qw + id.x;
    tmp_color[q] = c;
    tmp_coc[q] = k;
}

@compute @workgroup_size(64, 1, 1)
fn blur_horizontal(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.qw || id.y >= params.qh) {
        return;
    }
    let r = i32(params.radius);
    let row = id.y * params.qw;
    var c = vec4<f32>(0.0);
    var k = 0.0;
    for (var i = 0; i <= 2 * r; i++) {
        let x = u32(clamp(i32(id.x) + i - r, 0, i32(params.qw) - 1));
        c += kernel[i] * tmp_color[row + x];
        k += kernel[i] * tmp_coc[row + x];
    }
    large_color[row + id.x] = c;
    large_coc[row + id.x] = k;
}

// Listing 28-2 at quarter texel (x, y), clamped to the edge.
fn near_at(x: i32, y: i32) -> f32 {
    let q = u32(clamp(y, 0, i32(params.qh) - 1)) * params.qw
        + u32(clamp(x, 0, i32(params.qw) - 1));
    let s = shrunk_coc[q];
    return saturate1(2.0 * max(s, large_coc[q]) - s);
}

fn shrunk_at(x: i32, y: i32) -> vec4<f32> {
    let q = u32(clamp(y, 0, i32(params.qh) - 1)) * params.qw
        + u32(clamp(x, 0, i32(params.qw) - 1));
    return shrunk_color[q];
}

@compute @workgroup_size(64, 1, 1)
fn near_coc(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.qw || id.y >= params.qh) {
        return;
    }
    let x = i32(id.x);
    let y = i32(id.y);
    var c = vec4<f32>(0.0);
    var k = 0.0;
    // Listing 28-3: four bilinear taps half-way between texels, each the mean of 2x2.
    for (var t = 0; t < 4; t++) {
        let ox = select(-1, 0, t == 1 || t == 3);
        let oy = select(-1, 0, t >= 2);
        var tc = vec4<f32>(0.0);
        var tk = 0.0;
        for (var j = 0; j < 2; j++) {
            for (var i = 0; i < 2; i++) {
                tc += 0.25 * shrunk_at(x + ox + i, y + oy + j);
                tk += 0.25 * near_at(x + ox + i, y + oy + j);
            }
        }
        c += 0.25 * tc;
        k += 0.25 * tk;
    }
    let q = id.y * params.qw + id.x;
    medium_color[q] = c;
    medium_coc[q] = k;
}

// Bilinear sample of the full-res colour at (u, v) in pixels (pixel centres at +0.5), clamped.
fn color_bilinear(u: f32, v: f32) -> vec4<f32> {
    let fu = u - 0.5;
    let fv = v - 0.5;
    let i0 = floor(fu);
    let j0 = floor(fv);
    let ax = fu - i0;
    let ay = fv - j0;
    let w = i32(params.width);
    let h = i32(params.height);
    let x0 = u32(clamp(i32(i0), 0, w - 1));
    let x1 = u32(clamp(i32(i0) + 1, 0, w - 1));
    let y0 = u32(clamp(i32(j0), 0, h - 1)) * params.width;
    let y1 = u32(clamp(i32(j0) + 1, 0, h - 1)) * params.width;
    return (1.0 - ay) * ((1.0 - ax) * color[y0 + x0] + ax * color[y0 + x1])
        + ay * ((1.0 - ax) * color[y1 + x0] + ax * color[y1 + x1]);
}

// The four texels and weights of a bilinear sample at quarter-res (u, v), clamped.
struct Quad {
    i: vec4<u32>,
    w: vec4<f32>,
}

fn quarter_quad(u: f32, v: f32) -> Quad {
    let fu = u - 0.5;
    let fv = v - 0.5;
    let i0 = floor(fu);
    let j0 = floor(fv);
    let ax = fu - i0;
    let ay = fv - j0;
    let qw = i32(params.qw);
    let qh = i32(params.qh);
    let x0 = u32(clamp(i32(i0), 0, qw - 1));
    let x1 = u32(clamp(i32(i0) + 1, 0, qw - 1));
    let y0 = u32(clamp(i32(j0), 0, qh - 1)) * params.qw;
    let y1 = u32(clamp(i32(j0) + 1, 0, qh - 1)) * params.qw;
    var quad: Quad;
    quad.i = vec4<u32>(y0 + x0, y0 + x1, y1 + x0, y1 + x1);
    quad.w = vec4<f32>((1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay);
    return quad;
}

@compute @workgroup_size(64, 1, 1)
fn composite(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= params.width || id.y >= params.height) {
        return;
    }
    let i = id.y * params.width + id.x;
    let unblurred = color[i];
    let bits = depth_bits[i];
    if (bits == 0u || bits > INF_BITS) {
        out[i] = unblurred;
        return;
    }
    let px = f32(id.x) + 0.5;
    let py = f32(id.y) + 0.5;
    let quad = quarter_quad(px * 0.25, py * 0.25);
    var near = 0.0;
    for (var k = 0; k < 4; k++) {
        near += quad.w[k] * medium_coc[quad.i[k]];
    }
    let t = max(near, max(amount(bits), 0.0));
    if (t <= 0.0) {
        out[i] = unblurred;
        return;
    }
    var med = vec4<f32>(0.0);
    var big = vec4<f32>(0.0);
    for (var k = 0; k < 4; k++) {
        med += quad.w[k] * medium_color[quad.i[k]];
        big += quad.w[k] * large_color[quad.i[k]];
    }
    // Fig. 28-5: four bilinear taps of 2x2 pixels, 4/17 each; the centre's 1/17 comes in
    // through the blend with the unblurred colour.
    let small = (4.0 / 17.0) * (color_bilinear(px + 0.5, py - 1.5)
        + color_bilinear(px - 1.5, py - 0.5)
        + color_bilinear(px - 0.5, py + 1.5)
        + color_bilinear(px + 1.5, py + 0.5));
    let wt = clamp(t * params.lerp_scale + params.lerp_bias, vec4<f32>(0.0), vec4<f32>(1.0));
    let wy = min(wt.y, 1.0 - wt.x);
    let wz = min(wt.z, 1.0 - wt.y);
    let alpha = wy * (16.0 / 17.0) + wz + wt.w;
    out[i] = wy * small + wz * med + wt.w * big + (1.0 - alpha) * unblurred;
}
