// Float to integer conversions. lavapipe (Mesa 25.0, LLVM 15) compiles GLSL's uint(x)
// and int(x) of a float as saturating conversions one lane at a time (a scalar convert,
// compares and conditional moves a lane: sixteen of each a vector at 512-bit lanes; 4 %
// of a sample with Mitsuba's sampling on an Intel Xeon). f2u takes the float's bits
// instead: x clamped to [0, 2^23 - 1] (NaN to 0) with selects, floored, and added to 2^23,
// where a float's low mantissa bits are the integer: all of it vector instructions. The
// same value as uint(x) for every x below 2^23 (0 for NaN and for negatives, as uint(x)
// saturates there); every caller's x is a texel coordinate, an index or a count far below
// it (docs/benchmarks/rendering.md, "What lavapipe compiles lane by lane").
#ifndef CONVERT_GLSL
#define CONVERT_GLSL
const float F2U_MAX = 8388607.0;   // 2^23 - 1
uint f2u(float x) {
    float c = x > 0.0 ? x : 0.0;
    c = c < F2U_MAX ? c : F2U_MAX;
    return floatBitsToUint(floor(c) + 8388608.0) - 0x4B000000u;
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
