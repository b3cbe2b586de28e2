#version 430
// Quad splat: the corners are the warped centre plus the Jacobian times the half-pixel
// offsets (x +- 0.5, y +- 0.5), so neighbouring quads meet edge to edge.
layout(points) in;
layout(triangle_strip, max_vertices = 4) out;
in vec4 v_clip[];
in vec4 v_jac[];
flat in vec3 v_color[];
flat in float v_depth[];
uniform float u_max_splat;
uniform vec2 u_out_size;
flat out vec3 g_color;
flat out float g_depth;
void main() {
    vec4 c = v_clip[0];
    if (c.w <= 1e-6) return;
    vec3 ndc = c.xyz / c.w;
    vec2 jx = v_jac[0].xy, jy = v_jac[0].zw;
    float lim = u_max_splat * 2.0 / min(u_out_size.x, u_out_size.y);
    if (length(jx) > lim || length(jy) > lim) {   // over-stretched: fall back to one pixel
        jx = vec2(2.0 / u_out_size.x, 0.0);
        jy = vec2(0.0, 2.0 / u_out_size.y);
    }
    const vec2 offs[4] = vec2[](vec2(-0.5, -0.5), vec2(0.5, -0.5), vec2(-0.5, 0.5), vec2(0.5, 0.5));
    for (int k = 0; k < 4; ++k) {
        vec2 q = ndc.xy + jx * offs[k].x + jy * offs[k].y;
        gl_Position = vec4(q, ndc.z, 1.0);
        g_color = v_color[0];
        g_depth = v_depth[0];
        EmitVertex();
    }
    EndPrimitive();
}
