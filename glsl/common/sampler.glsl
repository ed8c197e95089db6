// Per-sample random numbers in two flavours, selected per render (`render.sampler`):
//   SAMPLER_INDEPENDENT - the PCG hash stream of rng.glsl (plain Monte Carlo);
//   SAMPLER_SOBOL       - Owen-scrambled Sobol (Burley 2020, "Practical Hash-based Owen
//                         Scrambling", JCGT 9(4)): each 1D/2D request is its own
//                         "padded" group with its own shuffle of the sample index and its
//                         own scramble, so the first two Sobol dimensions (a (0,2)-sequence)
//                         stratify every 2D pair (pixel jitter, light point, BSDF direction).
// Both are stateless in (pixel, sample index, seed): images do not depend on batch_spp.
// The independent sampler draws exactly the numbers rng.glsl drew before, in the same
// order, so its images are unchanged.
#ifndef SAMPLER_GLSL
#define SAMPLER_GLSL
#include "rng.glsl"

#define SAMPLER_INDEPENDENT 0u
#define SAMPLER_SOBOL 1u

struct Sampler {
    uint kind;
    Rng rng;          // independent stream
    uint pixel_seed;  // Sobol: per pixel and seed
    uint index;       // Sobol: sample index
    uint group;       // Sobol: next padded group
};

Sampler sampler_init(uint kind, uint pixel, uint sample_index, uint seed) {
    Sampler s;
    s.kind = kind;
    s.rng = rng_init(pixel, sample_index, seed);
    s.pixel_seed = pcg_hash(pixel ^ pcg_hash(seed ^ 0x68bc21ebu));
    s.index = sample_index;
    s.group = 0u;
    return s;
}

// Laine-Karras style hash permutation with Vegdahl's constants (as in Burley 2020).
uint lk_permute(uint x, uint seed) {
    x ^= x * 0x3d20adeau;
    x += seed;
    x *= (seed >> 16) | 1u;
    x ^= x * 0x05526c56u;
    x ^= x * 0x53a22864u;
    return x;
}

// Nested uniform (Owen) scramble of a 32-bit fixed-point value.
uint owen_scramble(uint x, uint seed) {
    return bitfieldReverse(lk_permute(bitfieldReverse(x), seed));
}

// First Sobol dimension: the van der Corput sequence (bit reversal).
uint sobol0(uint i) { return bitfieldReverse(i); }

// Second Sobol dimension (primitive polynomial x + 1): direction numbers v_k with
// v_0 = 2^31 and v_k = v_{k-1} ^ (v_{k-1} >> 1), so bit 31 - j of v_k is C(k, j) mod 2,
// 1 where the bits of j are among k's (Lucas). Bit 31 - j of the sum over i's bits k is
// then the parity of i's bits k whose bits include j's: the superset transform over
// GF(2) of i's bits read as a function of the 5-bit k, done in five shift-and-xor
// steps, not a loop over i's 32 bits (the same values as the loop).
uint sobol1(uint i) {
    i ^= (i >> 1) & 0x55555555u;
    i ^= (i >> 2) & 0x33333333u;
    i ^= (i >> 4) & 0x0f0f0f0fu;
    i ^= (i >> 8) & 0x00ff00ffu;
    i ^= (i >> 16) & 0x0000ffffu;
    return bitfieldReverse(i);
}

float u32_to_unit(uint x) { return float(x >> 8) * (1.0 / 16777216.0); }

vec2 sobol_group(inout Sampler s) {
    uint g = pcg_hash(s.pixel_seed ^ pcg_hash(s.group * 0x9e3779b9u + 1u));
    s.group++;
    uint i = owen_scramble(s.index, g);
    return vec2(u32_to_unit(owen_scramble(sobol0(i), pcg_hash(g ^ 0xa511e9b3u))),
                u32_to_unit(owen_scramble(sobol1(i), pcg_hash(g ^ 0x63d83595u))));
}

float sample_1d(inout Sampler s) {
    if (s.kind == SAMPLER_SOBOL) return sobol_group(s).x;
    return rng_next(s.rng);
}

vec2 sample_2d(inout Sampler s) {
    if (s.kind == SAMPLER_SOBOL) return sobol_group(s);
    float a = rng_next(s.rng);
    float b = rng_next(s.rng);
    return vec2(a, b);
}
#endif
