// Shared surface shading: used by the ground-truth renderer and by every server half
// that shades in object space (SAS, TSS, probes) so that what differs between a
// method and the ground truth is sampling, coding and latency, never the shader.
//
// Two models (Scene.shading): glTF 2.0 metallic-roughness ("pbr": base colour,
// metallic-roughness, normal, occlusion and emissive maps, GGX specular with
// Smith-GGX visibility and Schlick Fresnel for the sun and the point lights, a
// sky/ground environment term for the ambient), and the older Blinn-Phong on the
// base colour ("phong"), kept for comparison.  Light colours are scaled so that a
// white Lambertian surface facing a light reflects its colour (pi folded in).
#define MAX_POINT_LIGHTS 8
#define PI 3.14159265

uniform int u_shading_model;     // 0 = Blinn-Phong, 1 = glTF metallic-roughness
uniform vec3 u_sun_dir;          // direction the light travels (world, normalised)
uniform vec3 u_sun_color;        // colour * intensity
uniform vec3 u_ambient;
uniform vec3 u_sky_env;          // linear sky colour, the upper half of the specular environment
uniform int u_num_point;
uniform vec4 u_point_pos[MAX_POINT_LIGHTS];    // xyz position, w range (m)
uniform vec3 u_point_color[MAX_POINT_LIGHTS];  // colour * intensity
uniform vec3 u_base_color;
uniform float u_specular;
uniform float u_shininess;
uniform int u_has_texture;
uniform sampler2D u_albedo;
uniform float u_metallic;
uniform float u_roughness;
uniform int u_has_mr_map;
uniform sampler2D u_mr_map;            // G roughness, B metallic (linear)
uniform int u_has_normal_map;
uniform sampler2D u_normal_map;        // tangent space, linear
uniform float u_normal_scale;
uniform int u_has_occlusion_map;
uniform sampler2D u_occlusion_map;     // R occlusion (linear)
uniform float u_occlusion_strength;
uniform vec3 u_emissive;
uniform int u_has_emissive_map;
uniform sampler2D u_emissive_map;      // sRGB
uniform mat3 u_uv_transform;           // KHR_texture_transform of every map
uniform sampler2DShadow u_shadow_map;      // static casters, rendered once per scene
uniform sampler2DShadow u_shadow_map_dyn;  // animated casters, rendered per time
uniform mat4 u_light_vp;         // world -> light clip
uniform int u_has_shadow;

#include "ddgi.glsl"

// Diffuse ambient light (per pi, as the lights' colours): the scene's constant ambient on a
// hemisphere gradient, or with DDGI (u_gi) the probes' irradiance over pi.
vec3 ambient_diffuse(vec3 world_pos, vec3 n, vec3 v) {
    if (u_gi != 0) return gi_irradiance(world_pos, n, v) / PI;
    return u_ambient * (0.75 + 0.25 * n.y);
}

float shadow_factor(vec3 world_pos, vec3 n) {
    if (u_has_shadow == 0) return 1.0;
    vec3 p = world_pos + n * 0.03;
    vec4 lc = u_light_vp * vec4(p, 1.0);
    vec3 uvz = lc.xyz / lc.w * 0.5 + 0.5;
    if (uvz.x <= 0.0 || uvz.x >= 1.0 || uvz.y <= 0.0 || uvz.y >= 1.0 || uvz.z >= 1.0) return 1.0;
    vec2 texel = 1.0 / vec2(textureSize(u_shadow_map, 0));
    float s = 0.0;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            vec3 c = vec3(uvz.xy + vec2(dx, dy) * texel, uvz.z - 0.0015);
            s += min(texture(u_shadow_map, c), texture(u_shadow_map_dyn, c));
        }
    return s / 9.0;
}

// A shader including this file may define ALBEDO_LOOKUP(uv) first (e.g. a textureGrad
// with its own footprint); by default the albedo texture is sampled with texture().
#ifndef ALBEDO_LOOKUP
#define ALBEDO_LOOKUP(uv) texture(u_albedo, uv)
#endif
// The same for the other maps (normal, metallic-roughness, occlusion, emissive).  texture() takes its level from the
// fragment's derivatives; outside a fragment shader (tss's tessellation and compute gathering) it reads level 0,
// the unfiltered texture, so those shaders define MAP_LOOKUP with their own gradients.
#ifndef MAP_LOOKUP
#define MAP_LOOKUP(tex, uv) texture(tex, uv)
#endif

vec3 srgb_to_linear(vec3 c) { return pow(c, vec3(2.2)); }
vec3 linear_to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

vec3 tone_map(vec3 c) {
    // simple Reinhard-style tone map keeps highlights from clipping hard
    c = c / (1.0 + 0.15 * c);
    return linear_to_srgb(c);
}

// The older model: Blinn-Phong on the base colour (texture included), no other maps.
vec3 shade_phong(vec3 world_pos, vec3 n, vec2 uv, vec3 v) {
    vec3 albedo = u_base_color;
    if (u_has_texture != 0) albedo *= srgb_to_linear(ALBEDO_LOOKUP(uv).rgb);
    vec3 l = -u_sun_dir;
    float ndl = max(dot(n, l), 0.0);
    vec3 h = normalize(l + v);
    float spec = u_specular * pow(max(dot(n, h), 0.0), u_shininess) * step(0.0, ndl);
    float sh = shadow_factor(world_pos, n);
    vec3 c = albedo * ambient_diffuse(world_pos, n, v);
    c += (albedo * ndl + spec) * u_sun_color * sh;
    for (int i = 0; i < u_num_point; ++i) {
        vec3 d = u_point_pos[i].xyz - world_pos;
        float dist = length(d);
        vec3 pl = d / max(dist, 1e-4);
        float att = clamp(1.0 - dist / u_point_pos[i].w, 0.0, 1.0);
        att = att * att / (1.0 + dist * dist);
        float pndl = max(dot(n, pl), 0.0);
        vec3 ph = normalize(pl + v);
        float pspec = u_specular * pow(max(dot(n, ph), 0.0), u_shininess) * step(0.0, pndl);
        c += (albedo * pndl + pspec) * u_point_color[i] * att;
    }
    return c;
}

// Normal from the normal map in the frame (T, B = cross(n, T) * w, n).
vec3 mapped_normal(vec3 n, vec4 tangent, vec2 uv) {
    if (u_has_normal_map == 0) return n;
    vec3 t = tangent.xyz - n * dot(n, tangent.xyz);
    if (dot(t, t) < 1e-12) return n;
    t = normalize(t);
    vec3 b = cross(n, t) * (tangent.w < 0.0 ? -1.0 : 1.0);
    vec3 m = MAP_LOOKUP(u_normal_map, uv).rgb * 2.0 - 1.0;
    m.xy *= u_normal_scale;
    return normalize(mat3(t, b, n) * m);
}

// glTF BRDF (Schlick Fresnel, GGX distribution, height-correlated Smith-GGX visibility)
// times n.l, with pi folded into the light colour.
vec3 gltf_brdf(vec3 n, vec3 v, vec3 l, vec3 c_diff, vec3 f0, float a2, float ndv) {
    float ndl = dot(n, l);
    if (ndl <= 0.0) return vec3(0.0);
    vec3 h = normalize(l + v);
    float ndh = max(dot(n, h), 0.0);
    float vdh = max(dot(v, h), 0.0);
    vec3 F = f0 + (1.0 - f0) * pow(1.0 - vdh, 5.0);
    float dd = ndh * ndh * (a2 - 1.0) + 1.0;
    float D = a2 / (PI * dd * dd);
    float vis = 0.5 / max(ndl * sqrt(ndv * ndv * (1.0 - a2) + a2) + ndv * sqrt(ndl * ndl * (1.0 - a2) + a2), 1e-6);
    return ((1.0 - F) * c_diff + PI * F * D * vis) * ndl;
}

// Split-sum environment BRDF, analytic fit (Karis, "Physically based shading on mobile").
vec3 env_brdf(vec3 f0, float roughness, float ndv) {
    const vec4 c0 = vec4(-1.0, -0.0275, -0.572, 0.022);
    const vec4 c1 = vec4(1.0, 0.0425, 1.04, -0.04);
    vec4 r = roughness * c0 + c1;
    float a004 = min(r.x * r.x, exp2(-9.28 * ndv)) * r.x + r.y;
    vec2 ab = vec2(-1.04, 1.04) * a004 + r.zw;
    return f0 * ab.x + ab.y;
}

vec3 shade_pbr(vec3 world_pos, vec3 n_geo, vec4 tangent, vec2 uv, vec3 v) {
    vec3 base = u_base_color;
    if (u_has_texture != 0) base *= srgb_to_linear(ALBEDO_LOOKUP(uv).rgb);
    float metallic = u_metallic, roughness = u_roughness;
    if (u_has_mr_map != 0) {
        vec3 mr = MAP_LOOKUP(u_mr_map, uv).rgb;
        roughness *= mr.g;
        metallic *= mr.b;
    }
    roughness = clamp(roughness, 0.03, 1.0);
    metallic = clamp(metallic, 0.0, 1.0);
    float a2 = roughness * roughness * roughness * roughness;
    vec3 n = mapped_normal(n_geo, tangent, uv);
    float ndv = clamp(dot(n, v), 1e-4, 1.0);
    vec3 c_diff = base * (1.0 - metallic);
    vec3 f0 = mix(vec3(0.04), base, metallic);
    float ao = 1.0;
    if (u_has_occlusion_map != 0) ao = 1.0 + u_occlusion_strength * (MAP_LOOKUP(u_occlusion_map, uv).r - 1.0);
    // ambient: the hemisphere term of the older model for diffuse, a sky/ground
    // environment along the reflection for specular
    vec3 r = reflect(-v, n);
    vec3 env = mix(u_ambient, u_sky_env, smoothstep(-0.2, 0.4, r.y) * (1.0 - 0.7 * roughness));
    vec3 c = (c_diff * ambient_diffuse(world_pos, n, v) + env_brdf(f0, roughness, ndv) * env) * ao;
    float sh = shadow_factor(world_pos, n_geo);
    c += gltf_brdf(n, v, -u_sun_dir, c_diff, f0, a2, ndv) * u_sun_color * sh;
    for (int i = 0; i < u_num_point; ++i) {
        vec3 d = u_point_pos[i].xyz - world_pos;
        float dist = length(d);
        float att = clamp(1.0 - dist / u_point_pos[i].w, 0.0, 1.0);
        att = att * att / (1.0 + dist * dist);
        c += gltf_brdf(n, v, d / max(dist, 1e-4), c_diff, f0, a2, ndv) * u_point_color[i] * att;
    }
    vec3 e = u_emissive;
    if (u_has_emissive_map != 0) e *= srgb_to_linear(MAP_LOOKUP(u_emissive_map, uv).rgb);
    return c + e;
}

// Returns display-referred (sRGB-encoded) colour.  ``tangent``: xyz and handedness w
// (world space; only the normal map reads it).
vec3 shade(vec3 world_pos, vec3 normal, vec4 tangent, vec2 uv, vec3 eye_pos) {
    vec3 n = normalize(normal);
    vec3 v = normalize(eye_pos - world_pos);
    if (dot(n, v) < 0.0) n = -n;   // two-sided lighting
    vec2 tuv = (u_uv_transform * vec3(uv, 1.0)).xy;
    if (u_shading_model == 0) return tone_map(shade_phong(world_pos, n, tuv, v));
    return tone_map(shade_pbr(world_pos, n, tangent, tuv, v));
}
