// DDGI probe lookups (Majercik et al. 2019), included by shading.glsl.  Mirrors
// splitrender/gi/octa.py (octahedral map, guard bands) and splitrender/gi/ddgi.py (probe
// grid, texture layout).  Irradiance tiles are (IRR + 2)^2 texels, visibility tiles
// (VIS + 2)^2, probes row-major in u_gi_cols tiles per row; alpha of irradiance = active.
uniform int u_gi;                 // 1: the probes' irradiance replaces the ambient term
uniform sampler2D u_gi_irr;       // RGB irradiance E (cosine integral of radiance), A: probe active
uniform sampler2D u_gi_vis;       // R mean distance, G mean squared distance (metres)
uniform vec3 u_gi_origin;         // position of probe (0, 0, 0)
uniform vec3 u_gi_spacing;
uniform ivec3 u_gi_counts;
uniform int u_gi_cols;            // tiles per texture row
uniform int u_gi_irr_core;        // 8
uniform int u_gi_vis_core;        // 16
uniform float u_gi_bias;          // surface bias (metres) along the normal and the view

vec2 gi_oct_encode(vec3 d) {
    vec3 n = d / max(abs(d.x) + abs(d.y) + abs(d.z), 1e-20);
    vec2 p = n.xz;
    if (n.y < 0.0) p = (1.0 - abs(n.zx)) * vec2(n.x >= 0.0 ? 1.0 : -1.0, n.z >= 0.0 ? 1.0 : -1.0);
    return p;
}

vec2 gi_tile_uv(int probe, vec3 dir, int core, vec2 tex_size) {
    ivec2 tile = ivec2(probe % u_gi_cols, probe / u_gi_cols);
    vec2 inner = (gi_oct_encode(dir) * 0.5 + 0.5) * float(core);
    return (vec2(tile * (core + 2)) + 1.0 + inner) / tex_size;
}

// Irradiance at world_pos with normal n (facing the viewer v): the eight probes around
// the point, weighted by trilinear position, a wrapped cosine towards the probe and the
// Chebyshev visibility test of the probe's distance moments.
vec3 gi_irradiance(vec3 world_pos, vec3 n, vec3 v) {
    vec2 irr_size = vec2(textureSize(u_gi_irr, 0));
    vec2 vis_size = vec2(textureSize(u_gi_vis, 0));
    vec3 p = world_pos + (0.2 * n + 0.8 * v) * u_gi_bias;
    vec3 rel = (p - u_gi_origin) / u_gi_spacing;
    ivec3 base = clamp(ivec3(floor(rel)), ivec3(0), max(u_gi_counts - 2, ivec3(0)));
    vec3 alpha = clamp(rel - vec3(base), 0.0, 1.0);
    vec3 sum = vec3(0.0);
    float wsum = 0.0;
    for (int i = 0; i < 8; ++i) {
        ivec3 off = ivec3(i & 1, (i >> 1) & 1, (i >> 2) & 1);
        ivec3 pc = min(base + off, u_gi_counts - 1);
        int probe = pc.x + u_gi_counts.x * (pc.y + u_gi_counts.y * pc.z);
        vec4 irr = texture(u_gi_irr, gi_tile_uv(probe, n, u_gi_irr_core, irr_size));
        if (irr.a < 0.5) continue;                       // inactive probe
        vec3 ppos = u_gi_origin + vec3(pc) * u_gi_spacing;
        vec3 tri = mix(1.0 - alpha, alpha, vec3(off));
        vec3 to_probe = ppos - world_pos;
        float dl = length(to_probe);
        vec3 dir = dl > 1e-6 ? to_probe / dl : n;
        float w = (dot(dir, n) + 1.0) * 0.5;
        w = w * w + 0.2;
        vec3 pr = p - ppos;
        float r = length(pr);
        vec2 m = texture(u_gi_vis, gi_tile_uv(probe, r > 1e-6 ? pr / r : n, u_gi_vis_core, vis_size)).rg;
        if (r > m.x) {
            float var = abs(m.y - m.x * m.x);
            float d = r - m.x;
            float cheb = var / (var + d * d);
            w *= max(cheb * cheb * cheb, 0.0);
        }
        w = max(w, 1e-6);
        const float crush = 0.2;
        if (w < crush) w *= w * w / (crush * crush);
        w *= tri.x * tri.y * tri.z;
        sum += w * irr.rgb;
        wsum += w;
    }
    return wsum > 0.0 ? sum / wsum : vec3(0.0);
}
