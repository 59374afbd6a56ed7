// poisson::gather_pixel on the GPU, shared by `poisson` and `lowrank`'s fallback (prepended to
// their shaders after gpu/common.wgsl). It reads the module's `color`, `coc_px` and `taps`
// (x, y: the tap in the unit aperture, squeezed; z: its weight) and `params.width`,
// `params.height` and `params.tap_count`.
//
// At pixel (x, y) with CoC c each tap v reads the pixel nearest to p - c v, clamped to the
// image, weighted by the tap's weight times the depth rejection; pixels with |c| < 1/2 and
// pixels whose taps all weigh 0 keep their colour. With a cat's eye only the taps within
// `radius2` of `-shift` count (LensEffects::passes); without, `radius2` is the largest float.
fn gather_at(x: u32, y: u32, shift: vec2<f32>, radius2: f32) -> vec4<f32> {
    let w = params.width;
    let i = y * w + x;
    let c = coc_px[i];
    if (abs(c) < 0.5) {
        return color[i];
    }
    let max_x = f32(w) - 1.0;
    let max_y = f32(params.height) - 1.0;
    var acc = vec4<f32>(0.0);
    var total = 0.0;
    for (var k = 0u; k < params.tap_count; k++) {
        let tap = taps[k];
        let v = tap.xy;
        let s = v + shift;
        if (dot(s, s) > radius2) {
            continue;
        }
        let sx = u32(clamp(floor(f32(x) + 0.5 - c * v.x), 0.0, max_x));
        let sy = u32(clamp(floor(f32(y) + 0.5 - c * v.y), 0.0, max_y));
        let q = sy * w + sx;
        let wt = tap.z * rejection_weight(c, coc_px[q]);
        if (wt > 0.0) {
            acc += wt * color[q];
            total += wt;
        }
    }
    if (total > 0.0) {
        return acc / total;
    }
    return color[i];
}
