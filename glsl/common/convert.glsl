// Float to integer conversions. lavapipe (Mesa 25.0, LLVM 15) compiles GLSL's uint(x)
// and int(x) of a float as saturating conversions one lane at a time (a scalar convert,
// compares and conditional moves a lane: sixteen of each a vector at 512-bit lanes; 4 %
// of a sample with Mitsuba's sampling on an Intel Xeon). f2u and f2i take the float's
// bits instead, all of it vector instructions: x clamped with selects (NaN to 0); below
// 2^23 floored and added to 2^23, where a float's low mantissa bits are the integer; from
// 2^23 to 2^24 (floats that are integers) the mantissa with its implicit bit. f2u gives
// what that uint(x) gives for every x below 2^24 (0 for NaN and for negatives, as uint(x)
// saturates there), f2i what int(x) gives for |x| below 2^22; every caller's x is a texel
// coordinate, an index, a count or an octahedral normal's code (below 2^24) within them
// (docs/benchmarks/rendering.md, "What lavapipe compiles lane by lane"; test
// `float_to_integer_conversions_match_glsls_own`).
#ifndef CONVERT_GLSL
#define CONVERT_GLSL
const float F2U_MAX = 16777215.0;   // 2^24 - 1
uint f2u(float x) {
    float c = x > 0.0 ? x : 0.0;
    c = c < F2U_MAX ? c : F2U_MAX;
    uint low = floatBitsToUint(floor(c) + 8388608.0) - 0x4B000000u;   // c below 2^23
    uint high = (floatBitsToUint(c) & 0x7FFFFFu) | 0x800000u;          // c in [2^23, 2^24)
    return c < 8388608.0 ? low : high;
}
uvec3 f2u(vec3 x) {
    return uvec3(f2u(x.x), f2u(x.y), f2u(x.z));
}
// ivec3(x) for |x| below 2^22 (NaN to 0, as ivec3(x) saturates it), by the same trick
// about 1.5 x 2^23: x truncated toward zero, then added to it.
const float F2I_MAX = 4194303.0;   // 2^22 - 1
ivec3 f2i(vec3 x) {
    vec3 c = mix(vec3(0.0), x, equal(x, x));
    c = mix(vec3(F2I_MAX), c, lessThan(c, vec3(F2I_MAX)));
    c = mix(vec3(-F2I_MAX), c, greaterThan(c, vec3(-F2I_MAX)));
    return floatBitsToInt(trunc(c) + 12582912.0) - 0x4B400000;
}
#endif
