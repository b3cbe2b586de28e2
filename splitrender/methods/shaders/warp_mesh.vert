#version 430
// Grid-mesh reconstruction, vertex stage: warp each reference pixel centre; the
// geometry stage drops triangles across depth or object discontinuities.
#include "warp_common.glsl"
out vec3 v_color;
out float v_depth;
out float v_zref;             // reference depth, metres (0 = background)
flat out uint v_id;
void main() {
    ivec2 p = pixel_of(gl_VertexID);
    float z = ref_depth(p);
    uint id = ref_id(p);
    vec4 c = warp_clip(warp_matrix(id), vec2(p) + 0.5, z);
    gl_Position = c;
    v_color = texelFetch(u_color, p, 0).rgb;
    v_depth = z > 0.0 ? c.w : 1e30;
    v_zref = z;
    v_id = id;
}
