#version 430
// Same surface shading as the ground truth (forward.frag), evaluated per atlas texel
// in object space; view-dependent terms use the predicted eye position.
#include "shading.glsl"
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_tangent;
flat in vec4 v_rect;
uniform vec3 u_eye;
layout(location = 0) out vec4 f_color;
void main() {
    vec2 p = gl_FragCoord.xy;
    if (p.x < v_rect.x || p.y < v_rect.y || p.x > v_rect.x + v_rect.z || p.y > v_rect.y + v_rect.w) discard;
    vec3 n = normalize(v_normal);
    if (dot(n, u_eye - v_world) < 0.0) n = -n;
    f_color = vec4(shade(v_world, n, v_tangent, v_uv, u_eye), 1.0);
}
