#version 430
// Gathering stage, per triangle vertex: world-space attributes and the view depth at
// the reference (predicted) pose; the triangle's layout rides along, equal on its
// three vertices.
in vec3 in_position;   // object space
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_tangent;    // xyz object space, w handedness
in vec4 in_info;       // kind (0 single, 1 L-packing, 2 oversampling), level, perspective on, albedo lod
in vec4 in_o0;         // LP: tip 0 xy, tip 1 xy; OS: rectangle xy, its width, split fraction a; single: texel xy
in vec4 in_o1;         // LP: tip 2 xy; OS: bases w1, w2, height h, samples in all
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform mat4 u_view;   // reference view
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_tangent;
out float v_depth;
out vec4 v_info;
out vec4 v_o0;
out vec4 v_o1;
void main() {
    vec4 w = u_model * vec4(in_position, 1.0);
    v_world = w.xyz;
    v_normal = u_normal_matrix * in_normal;
    v_uv = in_uv;
    v_tangent = vec4(mat3(u_model) * in_tangent.xyz, in_tangent.w);
    v_depth = -(u_view * w).z;
    v_info = in_info;
    v_o0 = in_o0;
    v_o1 = in_o1;
    gl_Position = vec4(0.0);
}
