#version 430
// Point-splat reconstruction: one screen-aligned SxS point per reference pixel with
// S = ceil(max(|J11| + |J12|, |J21| + |J22|)) from the warp's Jacobian.  The mesh
// reconstruction reuses it for the pixels its cut triangles leave out (thin structures).
#include "warp_common.glsl"
uniform float u_max_splat;    // largest splat, pixels
uniform float u_splat_slack;  // size = ceil(S - slack); 0 = the paper's ceil
uniform int u_edge_only;      // 1: only pixels next to a discontinuity (the mesh's edge pass)
flat out vec3 v_color;
flat out float v_depth;       // current view depth along -Z, metres (1e30 = background)
void main() {
    ivec2 p = pixel_of(gl_VertexID);
    float z = ref_depth(p);
    uint id = ref_id(p);
    if (u_edge_only == 1) {
        bool edge = false;
        // the grid's edges: the four axis neighbours and the anti-diagonal of its triangles
        const ivec2 nb[6] = ivec2[](ivec2(1, 0), ivec2(-1, 0), ivec2(0, 1), ivec2(0, -1), ivec2(1, -1), ivec2(-1, 1));
        for (int k = 0; k < 6; ++k) {
            ivec2 q = clamp(p + nb[k], ivec2(0), u_ref_size - 1);
            edge = edge || discontinuous(z, id, ref_depth(q), ref_id(q));
        }
        if (!edge) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); gl_PointSize = 1.0; return; }
    }
    mat4 M = warp_matrix(id);
    vec4 c = warp_clip(M, vec2(p) + 0.5, z);
    gl_Position = c;
    v_color = texelFetch(u_color, p, 0).rgb;
    v_depth = z > 0.0 ? c.w : 1e30;
    if (c.w <= 1e-6) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); gl_PointSize = 1.0; return; }
    mat2 J = warp_jacobian(M, p, z, id, to_screen(c));
    float s = max(abs(J[0].x) + abs(J[1].x), abs(J[0].y) + abs(J[1].y));
    gl_PointSize = clamp(ceil(s - max(u_splat_slack, 1e-3)), 1.0, u_max_splat);
}
