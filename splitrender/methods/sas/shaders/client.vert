#version 430
// Display stage: all PVS triangles in one draw call; object transforms come from a
// storage buffer indexed per vertex, atlas coordinates are baked into the vertices.
layout(std430, binding = 0) readonly buffer Models { mat4 u_models[]; };
in vec3 in_position;   // object space
in vec2 in_atlas_uv;   // normalised atlas coordinates (the patch spans its whole block)
in float in_object;    // object slot
in vec4 in_clamp;      // the block's texel-centre rectangle, normalised (x0, y0, x1, y1)
uniform mat4 u_view;
uniform mat4 u_proj;
out vec2 v_uv;
flat out vec4 v_clamp;
void main() {
    mat4 m = u_models[int(in_object + 0.5)];
    v_uv = in_atlas_uv;
    v_clamp = in_clamp;
    gl_Position = u_proj * u_view * m * vec4(in_position, 1.0);
}
