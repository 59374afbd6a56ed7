// Half-precision colours, shared by the shaders that store fragments as the CPU's lists do
// (`raster.wgsl`, `multilayer.wgsl`; appended to each, WGSL having no includes).

// The half-precision bits of `v` (IEEE binary16, rounded to nearest, ties to even, as the
// CPU's `half` crate), clamped to the largest finite half as the CPU's `to_half`. Written out
// rather than `pack2x16float`, which naga allows only on devices with 16-bit float support.
fn half_bits(v: f32) -> u32 {
    let b = bitcast<u32>(v);
    let sign = (b >> 16u) & 0x8000u;
    let a = b & 0x7fffffffu;
    if a > 0x7f800000u {
        return sign | 0x7e00u;
    }
    if a >= 0x477fe000u {
        return sign | 0x7bffu;
    }
    if a < 0x38800000u {
        // Below the smallest normal half: a multiple of 2^-24, rounded (ties to even).
        return sign | u32(round(bitcast<f32>(a) * 16777216.0));
    }
    // Rebias the exponent (127 to 15) and round the mantissa to 10 bits, ties to even.
    return sign | ((a + 0xc8000fffu + ((a >> 13u) & 1u)) >> 13u);
}

// The f32 value of half-precision bits `h` (exact).
fn half_value(h: u32) -> f32 {
    let sign = (h & 0x8000u) << 16u;
    let e = (h >> 10u) & 0x1fu;
    let m = h & 0x3ffu;
    if e == 0u {
        return bitcast<f32>(sign) + select(1.0, -1.0, sign != 0u) * f32(m) * 5.9604645e-8;
    }
    if e == 31u {
        return bitcast<f32>(sign | 0x7f800000u | (m << 13u));
    }
    return bitcast<f32>(sign | ((e + 112u) << 23u) | (m << 13u));
}

// Premultiplied colour `c` in half precision, two words (low half first, as `pack2x16float`).
fn pack_half(c: vec4<f32>) -> vec2<u32> {
    return vec2<u32>(
        half_bits(c.x) | (half_bits(c.y) << 16u),
        half_bits(c.z) | (half_bits(c.w) << 16u),
    );
}

// A colour stored by `pack_half`.
fn unpack_half(c: vec2<u32>) -> vec4<f32> {
    return vec4<f32>(
        half_value(c.x & 0xffffu),
        half_value(c.x >> 16u),
        half_value(c.y & 0xffffu),
        half_value(c.y >> 16u),
    );
}
