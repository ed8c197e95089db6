// The surface at a hit: the object's `[material]` conductor (material id MAT_CONDUCTOR),
// the table (MAT_TABLE, Lambertian with prm.table_albedo) or an entry of the object's
// material table (MAT_REGION_FIRST + i, `[[material.region]]`: a rough conductor with
// its own alpha and IOR, or a Lambertian material). See docs/rendering.md, "Materials
// per region". Include after ggx.glsl and the Params block (reads prm).
#ifndef MATERIAL_GLSL
#define MATERIAL_GLSL
#ifndef PT_SURFACES
#error "include interface.glsl before material.glsl"
#endif

#ifndef PT_ADDR
#error "material.glsl reads the Surfaces binding through path_trace.comp's PT_ADDR"
#endif

struct Surface {
    bool diffuse;    // Lambertian with `albedo`; else the conductor `c`
    float albedo;
    Conductor c;
};

// `object`: the `[material]` conductor (from PathParams). Entries share its energy
// compensation switch; the tables E, E_avg are for F = 1 and hold for every IOR, f_avg
// is the entry's own.
Surface surface_of(uint mat, Conductor object) {
    Surface s;
    s.diffuse = mat == MAT_TABLE;
    s.albedo = prm.table_albedo;
    s.c = object;
    if (mat >= MAT_REGION_FIRST) {
        SurfaceBlock b = SurfaceRef(PT_ADDR(PT_SURFACES)).v[mat - MAT_REGION_FIRST];
        s.diffuse = b.kind == SURFACE_DIFFUSE;
        s.albedo = b.albedo;
        s.c.alpha = clamp(b.alpha, 1e-4, 1.0);
        s.c.n = b.ior_n;
        s.c.k = b.ior_k;
        s.c.f_avg = b.f_avg;
    }
    return s;
}

// f * cos and pdf of the surface at a hit, in the local frame (normal +z).
float surface_eval(Surface s, vec3 wo, vec3 wi, out float pdf) {
    if (s.diffuse) {
        pdf = wi.z > 0.0 ? wi.z / PI : 0.0;
        return wi.z > 0.0 && wo.z > 0.0 ? s.albedo / PI * wi.z : 0.0;
    }
    pdf = conductor_pdf(s.c, wo, wi);
    return conductor_eval_cos(s.c, wo, wi);
}

bool surface_sample(Surface s, vec3 wo, vec3 u, out vec3 wi, out float weight, out float pdf) {
    if (s.diffuse) {
        wi = cosine_hemisphere(u.y, u.z);
        pdf = wi.z / PI;
        weight = s.albedo;
        return wi.z > 0.0 && wo.z > 0.0;
    }
    return conductor_sample(s.c, wo, u, wi, weight, pdf);
}
#endif
