// Per-sample random numbers: a PCG hash (Jarzynski & Olano 2020, "Hash Functions for GPU
// Rendering") of (pixel, sample, seed, dimension). Stateless, so a sample's numbers do
// not depend on the batch it was rendered in: batches of any size give the same image.
#ifndef RNG_GLSL
#define RNG_GLSL
uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

struct Rng { uint state; };

Rng rng_init(uint pixel, uint sample_index, uint seed) {
    Rng r;
    r.state = pcg_hash(pixel ^ pcg_hash(sample_index ^ pcg_hash(seed + 0x9e3779b9u)));
    return r;
}

// Uniform in [0, 1): 24 bits, so 1.0 is never returned.
float rng_next(inout Rng r) {
    r.state = pcg_hash(r.state);
    return float(r.state >> 8) * (1.0 / 16777216.0);
}
#endif
