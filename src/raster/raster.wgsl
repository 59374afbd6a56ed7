// Views of a prepared scene drawn by the GPU's own rasteriser into a G-buffer, as the CPU's
// `GBuffer` sink does (raster/gbuffer.rs), and added up over the lens (raster/views.rs).
//
// Per view, four passes:
// 0. `setup` (compute): per triangle, the CPU's attribute planes (raster/setup.rs,
//    `setup_clipped`): the vertices projected, snapped to 1/256 pixel, put in the CPU's order,
//    and 1 / z, u / z and v / z as planes over the pixel grid, so that a fragment's depth and
//    texture coordinates are the CPU's to rounding, even where a sample lies exactly on a
//    texel's edge (charts drawn texel for texel). Triangles the CPU clips are marked, and
//    their fragments take the hardware's interpolation.
// 1. `opaque` (render): opaque and alpha-mask triangles, nearest first by the depth test, into
//    a colour target (linear, straight = premultiplied as alpha is 1) and a view-depth target.
// 2. `blended` (render): alpha-blended triangles; each fragment in front of the opaque surface
//    is appended to its pixel's list (capacity `view.info.z`; the count goes on past it, so
//    the CPU sees how many a pixel needed).
// 3. `composite` (compute): per pixel, the list sorted far to near (equal depths in scene
//    order) and composited over the opaque colour, the depth taken from the nearest surface
//    at least Z_ALPHA_THRESHOLD opaque, else the one with the largest weight, exactly as the
//    CPU's `GBufferTile::finish`; then added to the sum (or, in
//    store mode, written out as the G-buffer).
// Once per frame, `resolve` (compute) divides the sum by the number of views (or, with the
// cat's eye, by the views that reach each pixel).
//
// Shading is the CPU's (raster/shade.rs): unlit, base colour x texture + emission, textures
// sampled from their mip chains held in a storage buffer with the CPU's filter, wrap and level
// of detail (the forward difference of the texture coordinates one pixel right and down, on
// the triangle's plane, and the same approximate log2), so that the images agree with the CPU
// to rounding.

struct View {
    // x, y: the image point of the lens axis for this view, with its shear and pixel offset
    // (cx - offset.x + f vx / focus, cy - offset.y - f vy / focus); z: f in pixels; w: the
    // texture level-of-detail bias.
    a: vec4<f32>,
    // x, y: the lens point in camera space (metres); z, w: 2 / width, 2 / height.
    v: vec4<f32>,
    // x: near plane, y: far plane (metres), z: 1 / (1 - near / far); w: 1 / views.
    planes: vec4<f32>,
    // x, y: the lens point in aperture radii (image axes); z: barrel shift per pixel; w: barrel
    // radius (both in aperture radii).
    lens: vec4<f32>,
    // x: width, y: height, z: list capacity, w: flags (1 store the G-buffer, 2 clip by the
    // barrel, 4 front faces are clockwise on screen).
    info: vec4<u32>,
    // x: triangles; y: invocations a row of the setup pass; z: fragments a pixel keeps
    // (`collect`, `keep`).
    extra: vec4<u32>,
    // The fragment lists' CoC and reach (`keep`): x: f E (the CoC's scale, pixels times
    // metres), y: the focus distance (metres), z: reach in CoC radii (0: no guard band),
    // w: reach in pixels besides.
    coc: vec4<f32>,
    // The frame within the lists' pixels (`keep`): left, top, right, bottom.
    frame: vec4<u32>,
}

struct Slot {
    // x: texture index + 1 (0: no texture); y: mag + 4 min + 16 mip filter (0 nearest,
    // 1 linear; mip 0 none); z: wrap u + 4 wrap v (0 repeat, 1 clamp, 2 mirrored); w: 1 with
    // a UV transform.
    info: vec4<u32>,
    // scale.x, scale.y, sin, cos of the UV transform.
    affine: vec4<f32>,
    // offset.xy, origin.xy (the transform of (0, 0)).
    offset_origin: vec4<f32>,
    // Level-0 width and height in texels.
    size: vec4<f32>,
}

struct Material {
    base: vec4<f32>,
    // Emissive factor times strength.
    emission: vec4<f32>,
    // x: alpha mode (0 opaque, 1 mask, 2 blend); y: double-sided.
    mode: vec4<u32>,
    // x: alpha cutoff.
    cutoff: vec4<f32>,
    base_slot: Slot,
    emissive_slot: Slot,
}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> materials: array<Material>;
// Per texture: x its first level in `levels`, y its number of levels.
@group(0) @binding(2) var<storage, read> textures: array<vec4<u32>>;
// Per level: x its first texel, y width, z height.
@group(0) @binding(3) var<storage, read> levels: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> texels: array<vec4<f32>>;

// The blended pass's lists and the composite's inputs and outputs.
@group(0) @binding(5) var<storage, read_write> counts: array<atomic<u32>>;
// Per entry: depth bits, triangle index.
@group(0) @binding(6) var<storage, read_write> keys: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> colors: array<vec4<f32>>;
@group(0) @binding(8) var opaque_color: texture_2d<f32>;
@group(0) @binding(9) var opaque_depth: texture_2d<f32>;
@group(0) @binding(10) var<storage, read_write> sum: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> reached: array<u32>;
@group(0) @binding(12) var<storage, read_write> out_color: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read_write> out_depth: array<f32>;
// x: the most fragments a pixel's list was handed in any view; y: the nodes `collect` asked
// for (the pool holds `view.info.z`); z: the largest CoC diameter `keep` kept, as f32 bits.
@group(0) @binding(14) var<storage, read_write> status: array<atomic<u32>>;
// The vertex buffer as words: per vertex position (3), texture coordinates (2) as f32 bits,
// material and triangle index.
@group(0) @binding(15) var<storage, read> vertex_words: array<u32>;
// Per triangle (in draw order), three rows: (1/z plane, origin x), (u/z plane, origin y),
// (v/z plane, 1 where the planes hold).
@group(0) @binding(16) var<storage, read_write> planes: array<vec4<f32>>;

// The fragment lists of the layered methods (`collect`, `keep`), as the CPU's `FragmentLists`
// sampled at pixel centres (raster/fragments.rs): per pixel a linked list of every fragment
// (Yang et al. 2010, as Selgrad et al. section 4), 1 + the index of its first node (0: none).
@group(0) @binding(17) var<storage, read_write> heads: array<atomic<u32>>;
// Per node: depth bits, place in the draw; and (apart, so that each binding holds twice the
// nodes) its premultiplied colour as four halves.
@group(0) @binding(18) var<storage, read_write> nodes: array<vec2<u32>>;
@group(0) @binding(23) var<storage, read_write> node_color: array<vec2<u32>>;
// Per node: 1 + the index of the next node of its pixel (0: the last).
@group(0) @binding(19) var<storage, read_write> next_node: array<u32>;
// The N nearest fragments of each pixel, nearest first: their number, then N slots of depth
// and colour a pixel.
@group(0) @binding(20) var<storage, read_write> kept_count: array<u32>;
@group(0) @binding(21) var<storage, read_write> kept_depth: array<f32>;
@group(0) @binding(22) var<storage, read_write> kept_color: array<vec2<u32>>;

const STORE: u32 = 1u;
const CLIP: u32 = 2u;
const CLOCKWISE_FRONT: u32 = 4u;
// Entries a pixel's list can hold at most (the composite sorts them in registers).
const MAX_LIST: u32 = 16u;
// A blended surface this opaque gives the depth pass its depth (the CPU's `Z_ALPHA_THRESHOLD`).
const Z_ALPHA_THRESHOLD: f32 = 0.5;

struct Varyings {
    @builtin(position) position: vec4<f32>,
    // View depth in metres and the texture coordinates, interpolated with perspective.
    @location(0) z: f32,
    @location(1) uv: vec2<f32>,
    // Material, triangle index, the triangle's place in the draw.
    @location(2) @interpolate(flat) ids: vec3<u32>,
}

// The camera-space point `p` through the view's sheared projection (raster/mod.rs,
// `View::clip_from_camera`), in wgpu's clip space; depth reversed, 1 at the near plane and 0
// at the far one, so that the hardware clips where the CPU does.
@vertex
fn project(
    @location(0) p: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) ids: vec2<u32>,
    @builtin(vertex_index) vertex_index: u32,
) -> Varyings {
    let z = -p.z;
    let f = view.a.z;
    let hx = view.a.x * z + f * (p.x - view.v.x);
    let hy = view.a.y * z - f * (p.y - view.v.y);
    let near = view.planes.x;
    var o: Varyings;
    o.position = vec4<f32>(
        hx * view.v.z - z,
        z - hy * view.v.w,
        (near - near / view.planes.y * z) * view.planes.z,
        z,
    );
    o.z = z;
    o.uv = uv;
    o.ids = vec3<u32>(ids, vertex_index / 3u);
    return o;
}

// Words a vertex takes in `vertex_words`.
const VERTEX_WORDS: u32 = 7u;
// Steps of the CPU's fixed-point grid per pixel.
const SUBPIXEL: f32 = 256.0;
// The CPU's guard band, pixels beyond each side of the frame.
const GUARD_PX: f32 = 8192.0;

// `round` as the CPU's (`f64::round`: halves away from zero).
fn round_away(x: f32) -> f32 {
    return sign(x) * floor(abs(x) + 0.5);
}

@compute @workgroup_size(64)
fn setup(@builtin(global_invocation_id) id: vec3<u32>) {
    let t = id.y * view.extra.y + id.x;
    if t >= view.extra.x {
        return;
    }
    let f = view.a.z;
    let near = view.planes.x;
    let far = view.planes.y;
    let w = f32(view.info.x);
    let h = f32(view.info.y);
    var pos: array<vec2<f32>, 3>;
    var inv_w: array<f32, 3>;
    var uv: array<vec2<f32>, 3>;
    var valid = true;
    for (var k = 0u; k < 3u; k++) {
        let at = (3u * t + k) * VERTEX_WORDS;
        let p = vec3<f32>(
            bitcast<f32>(vertex_words[at]),
            bitcast<f32>(vertex_words[at + 1u]),
            bitcast<f32>(vertex_words[at + 2u]),
        );
        uv[k] = vec2<f32>(bitcast<f32>(vertex_words[at + 3u]), bitcast<f32>(vertex_words[at + 4u]));
        let z = -p.z;
        let hx = view.a.x * z + f * (p.x - view.v.x);
        let hy = view.a.y * z - f * (p.y - view.v.y);
        // The CPU clips a triangle with a vertex outside the planes or the guard band.
        if z < near || z > far || hx + GUARD_PX * z < 0.0 || (w + GUARD_PX) * z - hx < 0.0
            || hy + GUARD_PX * z < 0.0 || (h + GUARD_PX) * z - hy < 0.0 {
            valid = false;
        }
        let iw = 1.0 / z;
        inv_w[k] = iw;
        pos[k] = vec2<f32>(round_away(hx * iw * SUBPIXEL), round_away(hy * iw * SUBPIXEL)) / SUBPIXEL;
    }
    // Counter-clockwise front faces are negative in raster coordinates (y down): the CPU
    // swaps their second and third vertices.
    var order = vec3<u32>(0u, 2u, 1u);
    let e1 = pos[1] - pos[0];
    let e2 = pos[2] - pos[0];
    if e1.x * e2.y - e2.x * e1.y > 0.0 {
        order = vec3<u32>(0u, 1u, 2u);
    }
    let d1 = pos[order.y] - pos[order.x];
    let d2 = pos[order.z] - pos[order.x];
    let det = d1.x * d2.y - d2.x * d1.y;
    if !(det > 0.0) {
        valid = false;
    }
    var attr: array<vec3<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        attr[k] = vec3<f32>(inv_w[k], uv[k].x * inv_w[k], uv[k].y * inv_w[k]);
    }
    let a0 = attr[order.x];
    let a1 = attr[order.y] - a0;
    let a2 = attr[order.z] - a0;
    let px = (a1 * d2.y - a2 * d1.y) / det;
    let py = (a2 * d1.x - a1 * d2.x) / det;
    let origin = pos[order.x];
    let base = 3u * t;
    planes[base] = vec4<f32>(a0.x, px.x, py.x, origin.x);
    planes[base + 1u] = vec4<f32>(a0.y, px.y, py.y, origin.y);
    planes[base + 2u] = vec4<f32>(a0.z, px.z, py.z, select(0.0, 1.0, valid));
}

fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// log2 to about 0.01, as the CPU's `fast_log2` (the same quadratic on the mantissa).
fn fast_log2(x: f32) -> f32 {
    let bits = bitcast<u32>(x);
    let e = i32((bits >> 23u) & 0xffu) - 127;
    let m = bitcast<f32>((bits & 0x007fffffu) | 0x3f800000u);
    let t = m - 1.0;
    return f32(e) + t * (1.3465557 - 0.3465557 * t);
}

fn wrap(i: i32, n: i32, mode: u32) -> i32 {
    var r = i;
    if mode == 0u {
        r = i % n;
        if r < 0 {
            r += n;
        }
    } else if mode == 1u {
        r = clamp(i, 0, n - 1);
    } else {
        let period = 2 * n;
        var m = i % period;
        if m < 0 {
            m += period;
        }
        r = select(period - 1 - m, m, m < n);
    }
    return clamp(r, 0, n - 1);
}

// A texel coordinate far outside the texture brought near it without changing its texel.
fn reduce(x: f32, n: i32, mode: u32) -> f32 {
    if abs(x) < 16777216.0 {
        return x;
    }
    let nf = f32(n);
    if mode == 0u {
        return x - nf * floor(x / nf);
    } else if mode == 2u {
        return x - 2.0 * nf * floor(x / (2.0 * nf));
    }
    return clamp(x, -1.0, nf + 1.0);
}

fn texel(level: vec4<u32>, ix: i32, iy: i32) -> vec4<f32> {
    return texels[level.x + u32(iy) * level.y + u32(ix)];
}

// One mip level, filtered (`Texture::sample_level`).
fn sample_level(li: u32, linear: bool, wraps: u32, uv: vec2<f32>) -> vec4<f32> {
    let level = levels[li];
    let w = i32(level.y);
    let h = i32(level.z);
    let wu = wraps & 3u;
    let wv = (wraps >> 2u) & 3u;
    var x = uv.x * f32(w);
    var y = uv.y * f32(h);
    if !(is_finite(x) && is_finite(y)) {
        return texel(level, 0, 0);
    }
    x = reduce(x, w, wu);
    y = reduce(y, h, wv);
    if !linear {
        return texel(level, wrap(i32(floor(x)), w, wu), wrap(i32(floor(y)), h, wv));
    }
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x0 = floor(fx);
    let y0 = floor(fy);
    let tx = fx - x0;
    let ty = fy - y0;
    let xa = wrap(i32(x0), w, wu);
    let xb = wrap(i32(x0) + 1, w, wu);
    let ya = wrap(i32(y0), h, wv);
    let yb = wrap(i32(y0) + 1, h, wv);
    let p00 = texel(level, xa, ya);
    let p10 = texel(level, xb, ya);
    let p01 = texel(level, xa, yb);
    let p11 = texel(level, xb, yb);
    let top = p00 + (p10 - p00) * tx;
    let bottom = p01 + (p11 - p01) * tx;
    return top + (bottom - top) * ty;
}

// `Texture::sample_with`: level 0 when magnified or without mipmaps, else the level (nearest)
// or the two levels (linear) of `lod`.
fn sample_texture(t: u32, filters: u32, wraps: u32, uv: vec2<f32>, lod: f32) -> vec4<f32> {
    let tex = textures[t];
    let first = tex.x;
    let last = tex.y - 1u;
    let mag = (filters & 3u) == 1u;
    let min_linear = ((filters >> 2u) & 3u) == 1u;
    let mip = (filters >> 4u) & 3u;
    if lod <= 0.0 || mip == 0u {
        return sample_level(first, select(min_linear, mag, lod <= 0.0), wraps, uv);
    }
    let l = min(lod, f32(last));
    if mip == 1u {
        return sample_level(first + u32(l + 0.5), min_linear, wraps, uv);
    }
    let l0 = u32(l);
    let f = l - f32(l0);
    let a = sample_level(first + l0, min_linear, wraps, uv);
    if f <= 0.0 {
        return a;
    }
    let b = sample_level(first + min(l0 + 1u, last), min_linear, wraps, uv);
    return a + (b - a) * f;
}

fn transform_uv(s: Slot, uv: vec2<f32>) -> vec2<f32> {
    let p = uv * s.affine.xy;
    let sn = s.affine.z;
    let cs = s.affine.w;
    return vec2<f32>(cs * p.x + sn * p.y, -sn * p.x + cs * p.y) + s.offset_origin.xy;
}

// A slot's lookup at `uv` with the screen derivatives `dx`, `dy` (`Slot::sample`).
fn sample_slot(s: Slot, uv_in: vec2<f32>, dx_in: vec2<f32>, dy_in: vec2<f32>) -> vec4<f32> {
    var uv = uv_in;
    var dx = dx_in;
    var dy = dy_in;
    if s.info.w != 0u {
        uv = transform_uv(s, uv_in);
        dx = transform_uv(s, dx_in) - s.offset_origin.zw;
        dy = transform_uv(s, dy_in) - s.offset_origin.zw;
    }
    let a = dx * s.size.xy;
    let b = dy * s.size.xy;
    let fx = a.x * a.x + a.y * a.y;
    let fy = b.x * b.x + b.y * b.y;
    let lod = 0.5 * fast_log2(max(max(fx, fy), 1e-12)) + view.a.w;
    return sample_texture(s.info.x - 1u, s.info.y, s.info.z, uv, lod);
}

struct Shaded {
    color: vec4<f32>,
    keep: bool,
}

// The fragment's colour and alpha (`Shader::shade`), or `keep` false where an alpha-mask
// material discards it or a single-sided one is seen from behind.
// 1 / z, u / z, v / z at the fragment and their steps one pixel right and down: from the
// triangle's planes as the CPU evaluates them, or, for a triangle the CPU clips, from the
// hardware's interpolation and its differences in the pixel quad (exact for a plane).
struct Planes {
    at: vec3<f32>,
    dx: vec3<f32>,
    dy: vec3<f32>,
}

fn planes_at(v: Varyings) -> Planes {
    let q = 1.0 / v.z;
    let hw = vec3<f32>(q, v.uv.x * q, v.uv.y * q);
    var r: Planes;
    r.at = hw;
    r.dx = dpdxFine(hw);
    r.dy = dpdyFine(hw);
    let base = 3u * v.ids.z;
    let pq = planes[base];
    let pu = planes[base + 1u];
    let pv = planes[base + 2u];
    if pv.w != 0.0 {
        let dx = v.position.x - pq.w;
        let dy = v.position.y - pu.w;
        let p0 = vec3<f32>(pq.x, pu.x, pv.x);
        r.dx = vec3<f32>(pq.y, pu.y, pv.y);
        r.dy = vec3<f32>(pq.z, pu.z, pv.z);
        r.at = p0 + r.dx * dx + r.dy * dy;
    }
    return r;
}

fn shade(v: Varyings, pl: Planes, front_facing: bool) -> Shaded {
    let q = pl.at.x;
    let uq = pl.at.y;
    let vq = pl.at.z;
    let q_x = pl.dx.x;
    let q_y = pl.dy.x;
    let uq_x = pl.dx.y;
    let uq_y = pl.dy.y;
    let vq_x = pl.dx.z;
    let vq_y = pl.dy.z;
    var s: Shaded;
    s.keep = false;
    let m = materials[v.ids.x];
    let clockwise = (view.info.w & CLOCKWISE_FRONT) != 0u;
    if m.mode.y == 0u && front_facing == clockwise {
        return s;
    }
    let u = uq / q;
    let w = vq / q;
    let uv = vec2<f32>(u, w);
    let dx = vec2<f32>((uq + uq_x) / (q + q_x) - u, (vq + vq_x) / (q + q_x) - w);
    let dy = vec2<f32>((uq + uq_y) / (q + q_y) - u, (vq + vq_y) / (q + q_y) - w);
    var c = m.base;
    if m.base_slot.info.x != 0u {
        c *= sample_slot(m.base_slot, uv, dx, dy);
    }
    var e = m.emission.xyz;
    if m.emissive_slot.info.x != 0u {
        e *= sample_slot(m.emissive_slot, uv, dx, dy).xyz;
    }
    var alpha = 1.0;
    if m.mode.x == 1u {
        if c.w < m.cutoff.x {
            return s;
        }
    } else if m.mode.x == 2u {
        alpha = clamp(c.w, 0.0, 1.0);
    }
    s.color = vec4<f32>(c.xyz + e, alpha);
    s.keep = true;
    return s;
}

// The fragment's view depth: `1 / q` as on the CPU.
fn depth_of(pl: Planes) -> f32 {
    return 1.0 / pl.at.x;
}

struct Targets {
    @location(0) color: vec4<f32>,
    // View depth in metres; 0 where nothing was drawn.
    @location(1) depth: f32,
}

@fragment
fn opaque(v: Varyings, @builtin(front_facing) front_facing: bool) -> Targets {
    let pl = planes_at(v);
    let s = shade(v, pl, front_facing);
    if !s.keep {
        discard;
    }
    var t: Targets;
    t.color = s.color;
    t.depth = depth_of(pl);
    return t;
}

@fragment
fn blended(v: Varyings, @builtin(front_facing) front_facing: bool) {
    let pl = planes_at(v);
    let s = shade(v, pl, front_facing);
    if !s.keep {
        return;
    }
    let p = vec2<i32>(floor(v.position.xy));
    let d = depth_of(pl);
    let behind = textureLoad(opaque_depth, p, 0).x;
    if behind != 0.0 && d >= behind {
        return;
    }
    let pixel = u32(p.y) * view.info.x + u32(p.x);
    let k = atomicAdd(&counts[pixel], 1u);
    if k < view.info.z {
        let at = pixel * view.info.z + k;
        keys[at] = vec2<u32>(bitcast<u32>(d), v.ids.y);
        colors[at] = s.color;
    }
}

// True when entry `a` is composited before entry `b`: farther first, equal depths in scene
// order.
fn before(a: vec2<u32>, b: vec2<u32>) -> bool {
    let da = bitcast<f32>(a.x);
    let db = bitcast<f32>(b.x);
    return da > db || (da == db && a.y < b.y);
}

@compute @workgroup_size(64)
fn composite(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = view.info.x;
    if id.x >= width || id.y >= view.info.y {
        return;
    }
    let pixel = id.y * width + id.x;
    let p = vec2<i32>(id.xy);
    var color = textureLoad(opaque_color, p, 0);
    let raw = textureLoad(opaque_depth, p, 0).x;
    var depth = bitcast<f32>(0x7f800000u);
    if raw != 0.0 {
        depth = raw;
    }
    let handed = atomicLoad(&counts[pixel]);
    if handed != 0u {
        atomicStore(&counts[pixel], 0u);
        atomicMax(&status[0], handed);
        let n = min(handed, min(view.info.z, MAX_LIST));
        var key: array<vec2<u32>, MAX_LIST>;
        var src: array<vec4<f32>, MAX_LIST>;
        let base = pixel * view.info.z;
        // Insertion sort: far to near, stable in scene order.
        for (var i = 0u; i < n; i++) {
            let k = keys[base + i];
            let c = colors[base + i];
            var j = i;
            while j > 0u && before(k, key[j - 1u]) {
                key[j] = key[j - 1u];
                src[j] = src[j - 1u];
                j -= 1u;
            }
            key[j] = k;
            src[j] = c;
        }
        var best = select(0.0, 1.0, raw != 0.0);
        var passed = raw != 0.0;
        for (var i = 0u; i < n; i++) {
            let s = src[i];
            let a = s.w;
            color = vec4<f32>(s.xyz * a + color.xyz * (1.0 - a), a + color.w * (1.0 - a));
            best *= 1.0 - a;
            if a >= Z_ALPHA_THRESHOLD || (!passed && a > 0.0 && a >= best) {
                passed = passed || a >= Z_ALPHA_THRESHOLD;
                best = a;
                depth = bitcast<f32>(key[i].x);
            }
        }
    }
    let flags = view.info.w;
    if (flags & STORE) != 0u {
        out_color[pixel] = color;
        out_depth[pixel] = depth;
        return;
    }
    if (flags & CLIP) != 0u {
        let centre = vec2<f32>(f32(view.info.x), f32(view.info.y)) * 0.5;
        let shift = (vec2<f32>(id.xy) + 0.5 - centre) * view.lens.z;
        let r = view.lens.w;
        let d = view.lens.xy + shift;
        if dot(d, d) > r * r {
            return;
        }
        reached[pixel] += 1u;
    }
    sum[pixel] += color;
}

@compute @workgroup_size(64)
fn resolve(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = view.info.x;
    if id.x >= width || id.y >= view.info.y {
        return;
    }
    let pixel = id.y * width + id.x;
    var scale = view.planes.w;
    if (view.info.w & CLIP) != 0u {
        let k = reached[pixel];
        scale = select(0.0, 1.0 / f32(k), k > 0u);
    }
    out_color[pixel] = sum[pixel] * scale;
}

// Every fragment of every triangle, with no depth test, linked into its pixel's list: the
// fragments the CPU's `FragmentLists` sink is handed (alpha-mask cut-outs discarded, blended
// ones kept whatever their opacity, premultiplied). A pool of `view.info.z` nodes; the count
// goes on past it, so that the CPU sees how many the frame needed.
@fragment
fn collect(v: Varyings, @builtin(front_facing) front_facing: bool) {
    let pl = planes_at(v);
    let s = shade(v, pl, front_facing);
    let a = s.color.w;
    if !s.keep || !(a > 0.0) {
        return;
    }
    let p = vec2<u32>(floor(v.position.xy));
    let pixel = p.y * view.info.x + p.x;
    let node = atomicAdd(&status[1], 1u);
    if node >= view.info.z {
        return;
    }
    nodes[node] = vec2<u32>(bitcast<u32>(depth_of(pl)), v.ids.z);
    node_color[node] = pack_half(vec4<f32>(s.color.xyz * a, a));
    next_node[node] = atomicExchange(&heads[pixel], node + 1u);
}

// True when key `a` (depth bits, place in the draw) is kept before `b`: nearer first, equal
// depths in draw order (the CPU keeps the fragment that came first).
fn nearer(a: vec2<u32>, b: vec2<u32>) -> bool {
    let da = bitcast<f32>(a.x);
    let db = bitcast<f32>(b.x);
    return da < db || (da == db && a.x == b.x && a.y < b.y);
}

// The signed CoC radius in pixels of view depth `z` (lens/mod.rs, `coc_px`).
fn coc_of(z: f32) -> f32 {
    let zf = view.coc.y;
    return view.coc.x * (z - zf) / (zf * z);
}

// The depth from which a fragment of pixel `p` cannot reach the frame once blurred
// (raster/fragments.rs, `Reach::depth_limit`): +inf inside the frame.
fn reach_limit(p: vec2<u32>) -> f32 {
    let inf = bitcast<f32>(0x7f800000u);
    if view.coc.z <= 0.0 {
        return inf;
    }
    let px = vec2<f32>(p) + 0.5;
    let lo = vec2<f32>(view.frame.xy);
    let hi = vec2<f32>(view.frame.zw);
    let d2 = max(max(lo - px, px - hi), vec2<f32>(0.0));
    let d = sqrt(d2.x * d2.x + d2.y * d2.y);
    let r = (d - view.coc.w) / view.coc.z;
    let scale = view.coc.x;
    if r <= 0.0 || abs(scale / view.coc.y) >= r {
        return inf;
    }
    let inv_z = 1.0 / view.coc.y + r / scale;
    return select(inf, 1.0 / inv_z, inv_z > 0.0);
}

// Per pixel, the N nearest fragments of its list (`view.extra.z`), nearest first, into the
// kept slots; the largest CoC diameter among them into `status[2]`. The lists' heads are
// cleared for the next frame.
@compute @workgroup_size(64)
fn keep(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = view.info.x;
    if id.x >= width || id.y >= view.info.y {
        return;
    }
    let pixel = id.y * width + id.x;
    let cap = min(view.extra.z, MAX_LIST);
    let limit = reach_limit(id.xy);
    var key: array<vec2<u32>, MAX_LIST>;
    var col: array<vec2<u32>, MAX_LIST>;
    var n = 0u;
    var at = atomicExchange(&heads[pixel], 0u);
    while at != 0u {
        let node = at - 1u;
        at = next_node[node];
        let k = nodes[node];
        if !(bitcast<f32>(k.x) < limit) {
            continue;
        }
        if n == cap && !nearer(k, key[cap - 1u]) {
            continue;
        }
        var j = n;
        if n == cap {
            j = cap - 1u;
        } else {
            n += 1u;
        }
        while j > 0u && nearer(k, key[j - 1u]) {
            key[j] = key[j - 1u];
            col[j] = col[j - 1u];
            j -= 1u;
        }
        key[j] = k;
        col[j] = node_color[node];
    }
    kept_count[pixel] = n;
    var widest = 0.0;
    for (var i = 0u; i < n; i++) {
        let z = bitcast<f32>(key[i].x);
        kept_depth[pixel * cap + i] = z;
        kept_color[pixel * cap + i] = col[i];
        widest = max(widest, 2.0 * abs(coc_of(z)));
    }
    atomicMax(&status[2], bitcast<u32>(widest));
}
