// Shared surface shading: used by the ground-truth renderer and by every server half
// that shades in object space (SAS, TSS, probes) so that what differs between a
// method and the ground truth is sampling, coding and latency, never the shader.
#define MAX_POINT_LIGHTS 8

uniform vec3 u_sun_dir;          // direction the light travels (world, normalised)
uniform vec3 u_sun_color;        // colour * intensity
uniform vec3 u_ambient;
uniform int u_num_point;
uniform vec4 u_point_pos[MAX_POINT_LIGHTS];    // xyz position, w range (m)
uniform vec3 u_point_color[MAX_POINT_LIGHTS];  // colour * intensity
uniform vec3 u_base_color;
uniform float u_specular;
uniform float u_shininess;
uniform int u_has_texture;
uniform sampler2D u_albedo;
uniform sampler2DShadow u_shadow_map;      // static casters, rendered once per scene
uniform sampler2DShadow u_shadow_map_dyn;  // animated casters, rendered per time
uniform mat4 u_light_vp;         // world -> light clip
uniform int u_has_shadow;

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

vec3 srgb_to_linear(vec3 c) { return pow(c, vec3(2.2)); }
vec3 linear_to_srgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

// Returns display-referred (sRGB-encoded) colour.
vec3 shade(vec3 world_pos, vec3 normal, vec2 uv, vec3 eye_pos) {
    vec3 n = normalize(normal);
    vec3 albedo = u_base_color;
    if (u_has_texture != 0) albedo *= srgb_to_linear(ALBEDO_LOOKUP(uv).rgb);
    vec3 v = normalize(eye_pos - world_pos);
    if (dot(n, v) < 0.0) n = -n;   // two-sided lighting
    vec3 l = -u_sun_dir;
    float ndl = max(dot(n, l), 0.0);
    vec3 h = normalize(l + v);
    float spec = u_specular * pow(max(dot(n, h), 0.0), u_shininess) * step(0.0, ndl);
    float sh = shadow_factor(world_pos, n);
    vec3 c = albedo * u_ambient * (0.75 + 0.25 * n.y);
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
    // simple Reinhard-style tone map keeps highlights from clipping hard
    c = c / (1.0 + 0.15 * c);
    return linear_to_srgb(c);
}
