#version 430
// DDGI probe capture (splitrender/gi/ddgi.py): one cube face of one probe per draw, into
// its tile of the G-buffer atlas.  What a ray from the probe hits, for relighting later:
// position, normal (facing the probe), back-face flag, diffuse colour and emission.
#include "shading.glsl"
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_tangent;
in float v_view_depth;
flat in vec3 v_eye;           // the probe (per instance)
layout(location = 0) out vec4 o_pos;     // xyz world, w 1 (a hit)
layout(location = 1) out vec4 o_nrm;     // xyz normal facing the probe, w 1 on a back face
layout(location = 2) out vec4 o_diff;    // rgb diffuse colour (linear)
layout(location = 3) out vec4 o_emit;    // rgb emission (linear)
void main() {
    vec3 n = normalize(v_normal);
    float back = dot(n, v_eye - v_world) < 0.0 ? 1.0 : 0.0;
    if (back > 0.5) n = -n;
    vec2 tuv = (u_uv_transform * vec3(v_uv, 1.0)).xy;
    vec3 base = u_base_color;
    if (u_has_texture != 0) base *= srgb_to_linear(ALBEDO_LOOKUP(tuv).rgb);
    vec3 diff = base;
    if (u_shading_model != 0) {
        float metallic = u_metallic;
        if (u_has_mr_map != 0) metallic *= texture(u_mr_map, tuv).b;
        diff = base * (1.0 - clamp(metallic, 0.0, 1.0));
    }
    vec3 e = vec3(0.0);
    if (u_shading_model != 0) {
        e = u_emissive;
        if (u_has_emissive_map != 0) e *= srgb_to_linear(texture(u_emissive_map, tuv).rgb);
    }
    o_pos = vec4(v_world, 1.0);
    o_nrm = vec4(n, back);
    o_diff = vec4(diff, 1.0);
    o_emit = vec4(e, 1.0);
}
