// The rough conductor: GGX (Walter et al. 2007), separable Smith G2,
// visible-normal sampling (Heitz 2018), exact conductor Fresnel with complex IOR, and
// Kulla-Conty (2017) multiple-scattering compensation from tabulated E and E_avg.
// Mirrors src/render/bsdf.rs (the CPU reference the tests check) formula by formula.
// Local frame: normal = +z, wo towards the viewer, wi towards the light.
#ifndef GGX_GLSL
#define GGX_GLSL
const float PI = 3.14159265358979;

float ggx_d(float alpha, vec3 h) {
    if (h.z <= 0.0) return 0.0;
    float a2 = alpha * alpha;
    float t = h.z * h.z * (a2 - 1.0) + 1.0;
    return a2 / (PI * t * t);
}

float ggx_lambda(float alpha, vec3 w) {
    float c2 = max(w.z * w.z, 1e-12);
    float t2 = max((1.0 - c2) / c2, 0.0);
    return 0.5 * (-1.0 + sqrt(1.0 + alpha * alpha * t2));
}

float ggx_g1(float alpha, vec3 w) { return 1.0 / (1.0 + ggx_lambda(alpha, w)); }

// Separable G1(wo) G1(wi): see ggx_g2 in src/render/bsdf.rs for why.
float ggx_g2(float alpha, vec3 wo, vec3 wi) {
    return ggx_g1(alpha, wo) * ggx_g1(alpha, wi);
}

vec3 sample_vndf(float alpha, vec3 wo, float u1, float u2) {
    vec3 vh = normalize(vec3(alpha * wo.x, alpha * wo.y, wo.z));
    float lensq = vh.x * vh.x + vh.y * vh.y;
    vec3 t1 = lensq > 0.0 ? vec3(-vh.y, vh.x, 0.0) / sqrt(lensq) : vec3(1.0, 0.0, 0.0);
    vec3 t2 = cross(vh, t1);
    float r = sqrt(u1);
    float phi = 2.0 * PI * u2;
    float p1 = r * cos(phi);
    float p2 = r * sin(phi);
    float s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2;
    vec3 nh = p1 * t1 + p2 * t2 + sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh;
    return normalize(vec3(alpha * nh.x, alpha * nh.y, max(nh.z, 0.0)));
}

float vndf_reflect_pdf(float alpha, vec3 wo, vec3 wi) {
    if (wo.z <= 0.0 || wi.z <= 0.0) return 0.0;
    vec3 h = normalize(wo + wi);
    return ggx_g1(alpha, wo) * ggx_d(alpha, h) / (4.0 * wo.z);
}

float fresnel_conductor(float cos_i, float n, float k) {
    float c = clamp(cos_i, 0.0, 1.0);
    float c2 = c * c;
    float s2 = 1.0 - c2;
    float t0 = n * n - k * k - s2;
    float a2b2 = sqrt(t0 * t0 + 4.0 * n * n * k * k);
    float t1 = a2b2 + c2;
    float a = sqrt(max(0.5 * (a2b2 + t0), 0.0));
    float t2 = 2.0 * a * c;
    float rs = (t1 - t2) / (t1 + t2);
    float t3 = c2 * a2b2 + s2 * s2;
    float t4 = t2 * s2;
    float rp = rs * (t3 - t4) / (t3 + t4);
    return clamp(0.5 * (rp + rs), 0.0, 1.0);
}

vec3 cosine_hemisphere(float u1, float u2) {
    float r = sqrt(u1);
    float phi = 2.0 * PI * u2;
    return vec3(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u1, 0.0)));
}

// Energy tables (src/render/energy.rs): E at [alpha_row * N + mu], then E_avg[N].
#define ENERGY_N 32
#ifndef PT_ENERGY
#error "include interface.glsl (after trace.glsl) before ggx.glsl"
#endif
#ifndef PT_ADDR
#error "ggx.glsl reads the Energy binding through path_trace.comp's PT_ADDR"
#endif
float energy_at(uint i) { return FloatRef(PT_ADDR(PT_ENERGY)).v[i]; }

void energy_alpha_coord(float alpha, out uint j0, out float f) {
    float x = min(clamp(alpha, 0.0, 1.0) * float(ENERGY_N - 1), float(ENERGY_N - 1));
    j0 = min(f2u(floor(x)), uint(ENERGY_N - 2));
    f = x - float(j0);
}

float energy_e(float mu, float alpha) {
    float x = clamp(clamp(mu, 0.0, 1.0) * float(ENERGY_N) - 0.5, 0.0, float(ENERGY_N - 1));
    uint i0 = min(f2u(floor(x)), uint(ENERGY_N - 2));
    float fx = x - float(i0);
    uint j0; float fy;
    energy_alpha_coord(alpha, j0, fy);
    uint r0 = j0 * uint(ENERGY_N), r1 = (j0 + 1u) * uint(ENERGY_N);
    float a = mix(energy_at(r0 + i0), energy_at(r0 + i0 + 1u), fx);
    float b = mix(energy_at(r1 + i0), energy_at(r1 + i0 + 1u), fx);
    return mix(a, b, fy);
}

float energy_avg(float alpha) {
    uint j0; float f;
    energy_alpha_coord(alpha, j0, f);
    uint base = uint(ENERGY_N * ENERGY_N);
    return mix(energy_at(base + j0), energy_at(base + j0 + 1u), f);
}

struct Conductor {
    float alpha;
    float n;
    float k;
    bool comp;     // Kulla-Conty compensation on
    float f_avg;   // hemispherical average of the Fresnel term
};

float conductor_ms_prob(Conductor m, vec3 wo) {
    return m.comp ? clamp(1.0 - energy_e(wo.z, m.alpha), 0.0, 1.0) : 0.0;
}

float conductor_ms_eval_cos(Conductor m, vec3 wo, vec3 wi) {
    if (!m.comp) return 0.0;
    float e_avg = energy_avg(m.alpha);
    if (e_avg >= 1.0 - 1e-6) return 0.0;
    float f_ms = m.f_avg * m.f_avg * e_avg / (1.0 - m.f_avg * (1.0 - e_avg));
    return (1.0 - energy_e(wo.z, m.alpha)) * (1.0 - energy_e(wi.z, m.alpha))
        / (PI * (1.0 - e_avg)) * f_ms * wi.z;
}

float conductor_eval_cos(Conductor m, vec3 wo, vec3 wi) {
    if (wo.z <= 0.0 || wi.z <= 0.0) return 0.0;
    vec3 h = normalize(wo + wi);
    float ss = fresnel_conductor(dot(wo, h), m.n, m.k) * ggx_d(m.alpha, h)
        * ggx_g2(m.alpha, wo, wi) / (4.0 * wo.z);
    return ss + conductor_ms_eval_cos(m, wo, wi);
}

float conductor_pdf(Conductor m, vec3 wo, vec3 wi) {
    if (wo.z <= 0.0 || wi.z <= 0.0) return 0.0;
    float p = conductor_ms_prob(m, wo);
    return (1.0 - p) * vndf_reflect_pdf(m.alpha, wo, wi) + p * wi.z / PI;
}

// Returns false when no direction was produced; weight = f cos / pdf.
bool conductor_sample(Conductor m, vec3 wo, vec3 u, out vec3 wi, out float weight, out float pdf) {
    weight = 0.0; pdf = 0.0; wi = vec3(0.0, 0.0, 1.0);
    if (wo.z <= 0.0) return false;
    float p = conductor_ms_prob(m, wo);
    if (u.x < p) {
        wi = cosine_hemisphere(u.y, u.z);
    } else {
        vec3 h = sample_vndf(m.alpha, wo, u.y, u.z);
        wi = 2.0 * dot(wo, h) * h - wo;
    }
    if (wi.z <= 0.0) return false;
    pdf = conductor_pdf(m, wo, wi);
    if (!(pdf > 0.0)) return false;
    weight = conductor_eval_cos(m, wo, wi) / pdf;
    return true;
}
#endif
