#version 430
// Cut grid triangles at depth discontinuities (no rubber sheets between a foreground
// object and what lies behind it) and between a moving object and anything else.
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 v_color[];
in float v_depth[];
in float v_zref[];
flat in uint v_id[];
uniform float u_disc;
uniform sampler2D u_mats;
out vec3 g_color;
out float g_depth;
bool dyn(uint id) { return texelFetch(u_mats, ivec2(4, int(id)), 0).x > 0.5; }
bool cut(int a, int b) {
    float za = v_zref[a], zb = v_zref[b];
    if ((za <= 0.0) != (zb <= 0.0)) return true;
    if (v_id[a] != v_id[b] && (dyn(v_id[a]) || dyn(v_id[b]))) return true;
    return za > 0.0 && abs(za - zb) > u_disc * min(za, zb);
}
void main() {
    if (cut(0, 1) || cut(1, 2) || cut(0, 2)) return;
    for (int k = 0; k < 3; ++k) {
        if (gl_in[k].gl_Position.w <= 1e-6) return;
    }
    for (int k = 0; k < 3; ++k) {
        gl_Position = gl_in[k].gl_Position;
        g_color = v_color[k];
        g_depth = v_depth[k];
        EmitVertex();
    }
    EndPrimitive();
}
