// Shared by the GPU passes of several methods (prepended to their shaders): depth validity, the
// signed CoC of ThinLens::coc_px, the radius level of coc_map::level_of and the depth-rejection
// weight of poisson::rejection_weight. Depth is read as the bits of its f32, so +inf (the sky)
// and NaN are found without the shader relying on IEEE special values.

const INF_BITS: u32 = 0x7f800000u;
const ABS_MASK: u32 = 0x7fffffffu;
// CoC radii are quantised to steps of 1 / LEVELS_PER_PX pixel (coc_map::LEVELS_PER_PX).
const LEVELS_PER_PX: f32 = 4.0;
// No failing pixel in a status word.
const NO_FAILURE: u32 = 0xffffffffu;

// Valid depths are > 0: positive finite, or +inf. Zero, negatives (-0 included) and NaN are not.
fn depth_is_bad(bits: u32) -> bool {
    return bits == 0u || bits > INF_BITS;
}

// ThinLens::coc_px clamped to +-max_coc_px: C(z) = f E (z - z_f) / (z_f z); where z_f z
// overflows (z infinite or huge), f E / z_f.
fn coc_of_depth(bits: u32, f_times_e: f32, focus_m: f32, max_coc_px: f32) -> f32 {
    var ratio: f32;
    if (bits == INF_BITS) {
        ratio = 1.0 / focus_m;
    } else {
        let z = bitcast<f32>(bits);
        let den = focus_m * z;
        if ((bitcast<u32>(den) & ABS_MASK) == INF_BITS) {
            ratio = 1.0 / focus_m;
        } else {
            ratio = (z - focus_m) / den;
        }
    }
    let c = f_times_e * ratio;
    return min(max(c, -max_coc_px), max_coc_px);
}

// coc_map::level_of: |c| LEVELS_PER_PX rounded half away from zero, at most levels - 1.
fn level_in(c: f32, levels: u32) -> u32 {
    let v = abs(c) * LEVELS_PER_PX;
    let t = u32(v);
    var rounded = t;
    if (v - f32(t) >= 0.5) {
        rounded = t + 1u;
    }
    return min(rounded, levels - 1u);
}

// poisson::rejection_weight: a tap sharper and in front of the centre does not leak into it.
fn rejection_weight(c_centre: f32, c_tap: f32) -> f32 {
    if (c_tap >= c_centre) {
        return 1.0;
    }
    return min(abs(c_tap) / abs(c_centre), 1.0);
}
