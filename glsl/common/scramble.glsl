// Lavapipe hands each CPU thread one contiguous range of workgroups; in image order one
// thread then gets the sky and another the object. A bijective scramble of the workgroup
// index (multiplication by a number coprime with the count) spreads the work evenly.
// The host passes mult = 1 (no scramble) when count * mult could overflow 32 bits.
#ifndef SCRAMBLE_GLSL
#define SCRAMBLE_GLSL
uint scramble_group(uint group, uint count, uint mult) {
    return (group * mult) % count;
}
#endif
