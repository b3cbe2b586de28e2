#version 430
// Grid-mesh reconstruction, vertex stage.  The grid has (W + 2) x (H + 2) vertices:
// the inner W x H sit at the reference pixel centres, the outer ring on the image
// border (x = 0 or W, y = 0 or H) with the data of the nearest border pixel, so the
// mesh covers the whole reference image, not only the area between the outer pixel
// centres (which left a half-pixel frame of holes around the display at fov_scale 1).
// The geometry stage drops triangles across depth or object discontinuities.
#include "warp_common.glsl"
out vec3 v_color;
out float v_depth;
out float v_zref;             // reference depth, metres (0 = background)
flat out uint v_id;
void main() {
    int gw = u_ref_size.x + 2;
    ivec2 g = ivec2(gl_VertexID % gw, gl_VertexID / gw);
    ivec2 p = clamp(g - 1, ivec2(0), u_ref_size - 1);
    vec2 pc = clamp(vec2(g) - 0.5, vec2(0.0), vec2(u_ref_size));
    float z = ref_depth(p);
    uint id = ref_id(p);
    vec4 c = warp_clip(warp_matrix(id), pc, z);
    gl_Position = c;
    v_color = texelFetch(u_color, p, 0).rgb;
    v_depth = z > 0.0 ? c.w : 1e30;
    v_zref = z;
    v_id = id;
}
