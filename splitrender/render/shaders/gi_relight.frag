#version 430
// DDGI relighting (splitrender/gi/ddgi.py): the radiance every probe ray carries back,
// from the captured G-buffer atlas.  A hit reflects the direct light (sun with its
// shadow maps, point lights) and the previous bounce's probe irradiance diffusely, plus
// its emission; a back face is black; a miss sees the sky.
#include "shading.glsl"
uniform sampler2D u_cap_pos;
uniform sampler2D u_cap_nrm;
uniform sampler2D u_cap_diff;
uniform sampler2D u_cap_emit;
uniform ivec2 u_tile;             // (6 F, F): one probe's six faces side by side
uniform int u_tiles_per_row;
uniform int u_bounce;             // 0: direct light only
uniform vec3 u_sky;               // linear radiance of a ray that leaves the scene
layout(location = 0) out vec4 o_rad;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_cap_pos, px, 0);
    if (pos.w < 0.5) { o_rad = vec4(u_sky, 1.0); return; }
    vec4 nb = texelFetch(u_cap_nrm, px, 0);
    if (nb.w > 0.5) { o_rad = vec4(0.0, 0.0, 0.0, 1.0); return; }
    ivec2 tile = px / u_tile;
    int probe = tile.x + u_tiles_per_row * tile.y;
    ivec3 pc = ivec3(probe % u_gi_counts.x, (probe / u_gi_counts.x) % u_gi_counts.y, probe / (u_gi_counts.x * u_gi_counts.y));
    vec3 eye = u_gi_origin + vec3(pc) * u_gi_spacing;
    vec3 n = normalize(nb.xyz);
    vec3 diff = texelFetch(u_cap_diff, px, 0).rgb;
    vec3 v = normalize(eye - pos.xyz);
    vec3 e = vec3(0.0);
    e += u_sun_color * max(dot(n, -u_sun_dir), 0.0) * shadow_factor(pos.xyz, n);
    for (int i = 0; i < u_num_point; ++i) {
        vec3 d = u_point_pos[i].xyz - pos.xyz;
        float dist = length(d);
        float att = clamp(1.0 - dist / u_point_pos[i].w, 0.0, 1.0);
        att = att * att / (1.0 + dist * dist);
        e += u_point_color[i] * att * max(dot(n, d / max(dist, 1e-4)), 0.0);
    }
    if (u_bounce > 0) e += gi_irradiance(pos.xyz, n, v) / PI;
    o_rad = vec4(diff * e + texelFetch(u_cap_emit, px, 0).rgb, 1.0);
}
