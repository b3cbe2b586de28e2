#version 430
// One patch per triangle; all four tessellation factors equal (paper section 3.1):
// the L-packing level, the level whose v(l) covers the oversampled staircase, or 1
// for a single texel (only one of its three invocations shades).
layout(vertices = 3) out;
in vec3 v_world[];
in vec3 v_normal[];
in vec2 v_uv[];
in vec4 v_tangent[];
in float v_depth[];
in vec4 v_info[];
in vec4 v_o0[];
in vec4 v_o1[];
out vec3 c_world[];
out vec3 c_normal[];
out vec2 c_uv[];
out vec4 c_tangent[];
out float c_depth[];
patch out vec4 p_info;
patch out vec4 p_o0;
patch out vec4 p_o1;
void main() {
    c_world[gl_InvocationID] = v_world[gl_InvocationID];
    c_normal[gl_InvocationID] = v_normal[gl_InvocationID];
    c_uv[gl_InvocationID] = v_uv[gl_InvocationID];
    c_tangent[gl_InvocationID] = v_tangent[gl_InvocationID];
    c_depth[gl_InvocationID] = v_depth[gl_InvocationID];
    if (gl_InvocationID == 0) {
        p_info = v_info[0];
        p_o0 = v_o0[0];
        p_o1 = v_o1[0];
        float l = v_info[0].x < 0.5 ? 1.0 : v_info[0].y;
        gl_TessLevelOuter[0] = l;
        gl_TessLevelOuter[1] = l;
        gl_TessLevelOuter[2] = l;
        gl_TessLevelInner[0] = l;
    }
}
