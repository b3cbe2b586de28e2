#version 430
// Display stage: all PVS triangles in one draw call; object transforms come from a
// storage buffer indexed per vertex, atlas coordinates are baked into the vertices.
layout(std430, binding = 0) readonly buffer Models { mat4 u_models[]; };
in vec3 in_position;   // object space
in vec2 in_atlas_uv;   // normalised atlas coordinates (half-texel inset)
in float in_object;    // object slot
uniform mat4 u_view;
uniform mat4 u_proj;
out vec2 v_uv;
void main() {
    mat4 m = u_models[int(in_object + 0.5)];
    v_uv = in_atlas_uv;
    gl_Position = u_proj * u_view * m * vec4(in_position, 1.0);
}
