#version 430
// Quad-splat reconstruction, vertex stage: warp the pixel centre and pass the Jacobian
// (in NDC per reference pixel) to the geometry stage, which emits the quad.
#include "warp_common.glsl"
out vec4 v_clip;
out vec4 v_jac;               // (dNDC/dx, dNDC/dy)
flat out vec3 v_color;
flat out float v_depth;
void main() {
    ivec2 p = pixel_of(gl_VertexID);
    float z = ref_depth(p);
    uint id = ref_id(p);
    mat4 M = warp_matrix(id);
    vec4 c = warp_clip(M, vec2(p) + 0.5, z);
    v_clip = c;
    v_color = texelFetch(u_color, p, 0).rgb;
    v_depth = z > 0.0 ? c.w : 1e30;
    v_jac = vec4(0.0);
    if (c.w > 1e-6) {
        mat2 J = warp_jacobian(M, p, z, id, to_screen(c));
        vec2 k = 2.0 / u_out_size;
        v_jac = vec4(J[0] * k, J[1] * k);
    }
    gl_Position = c;
}
