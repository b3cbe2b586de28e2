#version 430
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_tangent;          // xyz object space, w handedness
uniform mat4 u_model;
uniform mat4 u_view;
uniform mat4 u_proj;
uniform mat3 u_normal_matrix;
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_tangent;
out float v_view_depth;
void main() {
    vec4 w = u_model * vec4(in_position, 1.0);
    v_world = w.xyz;
    v_normal = u_normal_matrix * in_normal;
    v_uv = in_uv;
    v_tangent = vec4(mat3(u_model) * in_tangent.xyz, in_tangent.w);
    vec4 vp = u_view * w;
    v_view_depth = -vp.z;
    gl_Position = u_proj * vp;
}
