#version 430
// Shading stage (paper section 3.2): each PVS triangle is drawn at its atlas block,
// already expanded on the CPU by a texel or so (attributes extrapolated linearly) so
// that every texel of the block is shaded, also along slanted edges; the block
// rectangle clips it in the fragment shader.
in vec2 in_atlas;      // atlas position, texels (x along width, y along rows)
in vec3 in_position;   // object space
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_tangent;    // xyz object space, w handedness
in vec4 in_rect;       // block x, y, w, h in texels
in vec2 in_footprint;  // atlas texels per display pixel along atlas x, y (>= 1)
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform vec2 u_atlas_size;
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_tangent;
flat out vec4 v_rect;
flat out vec2 v_footprint;
void main() {
    v_world = (u_model * vec4(in_position, 1.0)).xyz;
    v_normal = u_normal_matrix * in_normal;
    v_uv = in_uv;
    v_tangent = vec4(mat3(u_model) * in_tangent.xyz, in_tangent.w);
    v_rect = in_rect;
    v_footprint = in_footprint;
    gl_Position = vec4(in_atlas / u_atlas_size * 2.0 - 1.0, 0.0, 1.0);
}
