// `multilayer` on the GPU: the passes `filter` and `accumulate` of the CPU's filter.rs and
// accumulate.rs (the paper's box levels), one invocation an output cell or pixel.
//
// The levels lie in three shared buffers: per cell where its fragments start and how many
// there are, per slot a depth and a premultiplied colour in half precision (as the CPU's
// levels). Level 0 is the fragment lists (N slots a pixel, first in the slots); a filtered
// cell takes the slots it fills from a pool by an atomic counter (`status[0]`, which goes on
// past the pool so that the CPU sees how many the frame needed). The table says where each
// level's cells start, where its cells sit on the image, and which depths it can serve (the
// accumulation's gates).
//
// - `step` (section 5): one cell of a filtered level from four cells of the level before it
//   (a mip step: the 2x2 cells under it; a stack step: the four cells `d` apart, borders
//   clamped), merged as the CPU's `merge4`: the nearest remaining fragment of the four opens
//   a merged fragment, every fragment within `epsilon` times its depth joins; over within a
//   source list, the four sums averaged; the depth the opacity-weighted mean; truncation
//   (section 6.2) drops what the level will never be asked for.
// - `accumulate` (section 6.1): per pixel, every level's fragment whose level weight is above
//   0 (the two levels around `log2(sqrt(3) |C|)`, blended to the disc's variance), sorted by
//   depth (equal depths in level order), grouped within `epsilon`, over within a level and
//   summed across levels, the groups composited front to back; and the pixel's nearest depth.

struct LevelInfo {
    // Cells per row, rows, the most fragments a cell holds, first cell.
    dims: vec4<u32>,
    // x: image pixels from one cell to the next; y: the image position of cell (0, 0)'s
    // centre.
    place: vec4<f32>,
    // The depths the level can serve (accumulate.rs, `accumulate_with`): it skips a depth
    // `z <= x || z >= y || (z > z && z < w)`.
    gates: vec4<f32>,
}

struct Params {
    // x: source level (`accumulate`: the first level accumulated), y: output level, z: 0 mip
    // step, 1 stack step, w: the stack step's distance in cells.
    levels: vec4<u32>,
    // x: epsilon; y: 1 with truncation; z: the output level's index; w: f E (the CoC's scale).
    consts: vec4<f32>,
    // x: the focus distance; y: the number of levels in the table.
    lens: vec4<f32>,
    // The pixels output (`accumulate`): left, top, width, height in the levels' frame.
    region: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> table: array<LevelInfo>;
// Per cell: its first slot, its number of fragments.
@group(0) @binding(2) var<storage, read_write> cell_span: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read_write> slot_depth: array<f32>;
@group(0) @binding(4) var<storage, read_write> slot_color: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read_write> out_color: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out_depth: array<f32>;
// The fragment lists' counts (`spans`).
@group(0) @binding(7) var<storage, read> list_count: array<u32>;
// x: slots taken (level 0's and the filtered levels'); y: the slots the pool holds.
@group(0) @binding(8) var<storage, read_write> status: array<atomic<u32>>;

// Slots a cell of a filtered level holds (the farthest merged fragments beyond are dropped;
// the CPU keeps 64).
const LEVEL_CAP: u32 = 16u;
// Weighted fragments a pixel's accumulation holds (the farthest beyond are dropped).
const MAX_ENTRIES: u32 = 32u;
// Levels at most (the CPU's `MAX_FILTER_STEPS` + 1).
const MAX_LEVELS: u32 = 11u;

fn inf() -> f32 {
    return bitcast<f32>(0x7f800000u);
}

// The level coordinate of view depth `z` (mod.rs, `Borders::lambda`): log2 of sqrt(3) |C|.
fn lambda(z: f32) -> f32 {
    let zf = params.lens.x;
    let c = params.consts.w * (z - zf) / (zf * z);
    return log2(sqrt(3.0) * abs(c));
}

// The cells of a source row or column paired into output cell `i` (filter.rs, `step_row`).
fn pair(i: u32, n: u32) -> vec2<u32> {
    let d = params.levels.w;
    if params.levels.z == 0u {
        return vec2<u32>(min(2u * i, n - 1u), min(2u * i + 1u, n - 1u));
    }
    if d == 1u {
        return vec2<u32>(i, min(i + 1u, n - 1u));
    }
    let half = d / 2u;
    return vec2<u32>(select(0u, i - half, i >= half), min(i + half, n - 1u));
}

@compute @workgroup_size(64)
fn step(@builtin(global_invocation_id) id: vec3<u32>) {
    let src = table[params.levels.x];
    let dst = table[params.levels.y];
    if id.x >= dst.dims.x || id.y >= dst.dims.y {
        return;
    }
    let px = pair(id.x, src.dims.x);
    let py = pair(id.y, src.dims.y);
    var first: array<u32, 4>;
    var len: array<u32, 4>;
    var idx: array<u32, 4>;
    let cells = array<vec2<u32>, 4>(
        vec2<u32>(px.x, py.x),
        vec2<u32>(px.y, py.x),
        vec2<u32>(px.x, py.y),
        vec2<u32>(px.y, py.y),
    );
    for (var j = 0u; j < 4u; j++) {
        let span = cell_span[src.dims.w + cells[j].y * src.dims.x + cells[j].x];
        first[j] = span.x;
        len[j] = span.y;
        idx[j] = 0u;
    }
    let cell = id.y * dst.dims.x + id.x;
    let cap = min(dst.dims.z, LEVEL_CAP);
    var merged_depth: array<f32, LEVEL_CAP>;
    var merged_color: array<vec2<u32>, LEVEL_CAP>;
    let eps = params.consts.x;
    let truncate = params.consts.y != 0.0;
    let s = params.consts.z;
    var emitted = 0u;
    loop {
        // The nearest remaining fragment opens the merged fragment.
        var z0 = inf();
        var any = false;
        for (var j = 0u; j < 4u; j++) {
            if idx[j] < len[j] {
                let z = slot_depth[first[j] + idx[j]];
                if !any || z < z0 {
                    z0 = z;
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let limit = z0 + eps * abs(z0);
        var p = vec4<f32>(0.0);
        var dw = 0.0;
        var ds = 0.0;
        for (var j = 0u; j < 4u; j++) {
            var part = vec4<f32>(0.0);
            var pw = 0.0;
            var ps = 0.0;
            while idx[j] < len[j] {
                let k = first[j] + idx[j];
                let z = slot_depth[k];
                if z > limit {
                    break;
                }
                let c = unpack_half(slot_color[k]);
                let t = 1.0 - part.w;
                part += t * c;
                let w = t * c.w;
                pw += w;
                ps += w * z;
                idx[j] += 1u;
            }
            p += 0.25 * part;
            dw += pw;
            ds += ps;
        }
        let z = select(z0, ds / dw, dw > 0.0);
        let kept = !truncate || lambda(z) > s - 1.0;
        if p.w > 0.0 && kept && emitted < cap {
            merged_depth[emitted] = z;
            merged_color[emitted] = pack_half(p);
            emitted += 1u;
        }
    }
    var span = vec2<u32>(0u, 0u);
    if emitted > 0u {
        let at = atomicAdd(&status[0], emitted);
        if at + emitted <= atomicLoad(&status[1]) {
            for (var k = 0u; k < emitted; k++) {
                slot_depth[at + k] = merged_depth[k];
                slot_color[at + k] = merged_color[k];
            }
            span = vec2<u32>(at, emitted);
        }
    }
    cell_span[dst.dims.w + cell] = span;
}

// Level 0's spans: pixel `i` holds `list_count[i]` fragments from slot `i * N`.
@compute @workgroup_size(64)
fn spans(@builtin(global_invocation_id) id: vec3<u32>) {
    let level = table[0];
    if id.x >= level.dims.x || id.y >= level.dims.y {
        return;
    }
    let i = id.y * level.dims.x + id.x;
    cell_span[level.dims.w + i] = vec2<u32>(i * level.dims.z, min(list_count[i], level.dims.z));
}

// Weight of level `s` of `n` for a fragment at level coordinate `l` (accumulate.rs,
// `level_weight`).
fn level_weight(l_in: f32, s: u32, n: u32) -> f32 {
    let top = f32(n - 1u);
    let l = clamp(l_in, 0.0, top);
    let base = floor(l);
    var t = 0.0;
    if base < top {
        t = (pow(4.0, l - base) - 1.0) / 3.0;
    }
    let b = u32(base);
    if s == b {
        return 1.0 - t;
    }
    if s == b + 1u {
        return t;
    }
    return 0.0;
}

// The cell of `level` whose centre is nearest to the centre of image pixel `p` along one axis
// of `n` cells (filter.rs, `Level::cell_of_pixel`).
fn cell_of(p: u32, n: u32, level: LevelInfo) -> u32 {
    let t = (f32(p) + 0.5 - level.place.y) / level.place.x + 0.5;
    return min(u32(max(t, 0.0)), n - 1u);
}

@compute @workgroup_size(64)
fn accumulate(@builtin(global_invocation_id) id: vec3<u32>) {
    let region = params.region;
    if id.x >= region.z || id.y >= region.w {
        return;
    }
    let x = id.x + region.x;
    let y = id.y + region.y;
    // The levels accumulated: from `params.levels.x` (after the supersampled lists' merges).
    let first_level = params.levels.x;
    let n_levels = u32(params.lens.y) - first_level;
    let eps = params.consts.x;
    var ed: array<f32, MAX_ENTRIES>;
    var el: array<u32, MAX_ENTRIES>;
    var ew: array<f32, MAX_ENTRIES>;
    var ec: array<vec2<u32>, MAX_ENTRIES>;
    var n = 0u;
    for (var s = 0u; s < n_levels; s++) {
        let level = table[first_level + s];
        let cx = cell_of(x, level.dims.x, level);
        let cy = cell_of(y, level.dims.y, level);
        let span = cell_span[level.dims.w + cy * level.dims.x + cx];
        let count = span.y;
        let first = span.x;
        let g = level.gates;
        for (var k = 0u; k < count; k++) {
            let z = slot_depth[first + k];
            if z <= g.x || z >= g.y || (z > g.z && z < g.w) {
                continue;
            }
            let weight = level_weight(lambda(z), s, n_levels);
            if !(weight > 0.0) {
                continue;
            }
            // Stable insertion by depth; full, the farthest is dropped.
            if n == MAX_ENTRIES && z >= ed[MAX_ENTRIES - 1u] {
                continue;
            }
            var j = min(n, MAX_ENTRIES - 1u);
            if n < MAX_ENTRIES {
                n += 1u;
            }
            while j > 0u && ed[j - 1u] > z {
                ed[j] = ed[j - 1u];
                el[j] = el[j - 1u];
                ew[j] = ew[j - 1u];
                ec[j] = ec[j - 1u];
                j -= 1u;
            }
            ed[j] = z;
            el[j] = s;
            ew[j] = weight;
            ec[j] = slot_color[first + k];
        }
    }
    // Front-to-back groups (accumulate.rs, `composite`).
    var out = vec4<f32>(0.0);
    var transmit = 1.0;
    var level_transmit: array<f32, MAX_LEVELS>;
    var i = 0u;
    while i < n && transmit > 1e-5 {
        let z0 = ed[i];
        let limit = z0 + eps * abs(z0);
        for (var s = 0u; s < MAX_LEVELS; s++) {
            level_transmit[s] = 1.0;
        }
        var p = vec4<f32>(0.0);
        while i < n && ed[i] <= limit {
            let c = unpack_half(ec[i]);
            let l = el[i];
            p += level_transmit[l] * ew[i] * c;
            level_transmit[l] *= 1.0 - c.w;
            i += 1u;
        }
        var scale = 1.0;
        if p.w > 1.0 {
            scale = 1.0 / p.w;
        }
        let a = clamp(p.w * scale, 0.0, 1.0);
        out = vec4<f32>(out.xyz + transmit * p.xyz * scale, out.w + transmit * a);
        transmit *= 1.0 - a;
    }
    let pixel = id.y * region.z + id.x;
    out_color[pixel] = out;
    let level0 = table[first_level];
    let span0 = cell_span[level0.dims.w + y * level0.dims.x + x];
    var depth = inf();
    if span0.y > 0u {
        depth = slot_depth[span0.x];
    }
    out_depth[pixel] = depth;
}
