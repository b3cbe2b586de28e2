#version 430
// Same surface shading as the ground truth (forward.frag), evaluated per atlas texel
// in object space; view-dependent terms use the predicted eye position.  Textures are
// filtered for the display's footprint, not the atlas texel's: where a block holds
// more texels than the patch covers pixels (power-of-two rounding, smallest blocks),
// the gradients are scaled by v_footprint (atlas texels per display pixel along atlas
// x and y, >= 1), so the pre-filtered atlas is what a mip-mapped forward render shows.
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_tangent;
flat in vec4 v_rect;
flat in vec2 v_footprint;
vec2 g_duv_dx, g_duv_dy;   // texture-coordinate gradients, taken before any discard
#define ALBEDO_LOOKUP(uv) textureGrad(u_albedo, uv, g_duv_dx * v_footprint.x, g_duv_dy * v_footprint.y)
#include "shading.glsl"
uniform vec3 u_eye;
layout(location = 0) out vec4 f_color;
void main() {
    g_duv_dx = dFdx(v_uv);
    g_duv_dy = dFdy(v_uv);
    vec2 p = gl_FragCoord.xy;
    if (p.x < v_rect.x || p.y < v_rect.y || p.x > v_rect.x + v_rect.z || p.y > v_rect.y + v_rect.w) discard;
    vec3 n = normalize(v_normal);
    if (dot(n, u_eye - v_world) < 0.0) n = -n;
    f_color = vec4(shade(v_world, n, v_tangent, v_uv, u_eye), 1.0);
}
