#version 430
// Display stage: all live triangles in one draw; object transforms from a storage
// buffer; each vertex carries its triangle's layout and reference-view depths.
layout(std430, binding = 0) readonly buffer Models { mat4 u_models[]; };
in vec3 in_position;   // object space
in float in_object;
in vec3 in_zref;       // the triangle's three vertex depths at the reference view (m)
in vec4 in_info;       // kind, level, perspective on, -
in vec4 in_o0;         // as the server's gathering stage (tss_shade.vert)
in vec4 in_o1;
uniform mat4 u_view;
uniform mat4 u_proj;
out vec3 v_bary;
flat out vec3 v_zref;
flat out vec4 v_info;
flat out vec4 v_o0;
flat out vec4 v_o1;
void main() {
    int c = gl_VertexID % 3;
    v_bary = vec3(c == 0, c == 1, c == 2);
    v_zref = in_zref;
    v_info = in_info;
    v_o0 = in_o0;
    v_o1 = in_o1;
    gl_Position = u_proj * u_view * u_models[int(in_object + 0.5)] * vec4(in_position, 1.0);
}
