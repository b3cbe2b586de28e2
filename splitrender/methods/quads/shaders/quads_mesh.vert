#version 430
// The layered quad mesh: world-space corners, homogeneous atlas pixel coordinates (u z, v z, z)
// with z the source camera's depth, the quad's atlas rect, the quad's view (0: the centre view).
in vec3 in_pos;
in vec3 in_uvw;
in vec4 in_rect;
in float in_view;
uniform mat4 u_view;
uniform mat4 u_proj;
uniform float u_view_bias;    // a later view's corners pushed back along their rays by this fraction (same pixel)
out vec3 v_uvw;
flat out vec4 v_rect;
out float v_depth;
out vec3 v_world;
flat out float v_view;
void main() {
    v_uvw = in_uvw;
    v_rect = in_rect;
    v_depth = -(u_view * vec4(in_pos, 1.0)).z;
    v_world = in_pos;
    v_view = in_view;
    vec4 e = u_view * vec4(in_pos, 1.0);
    if (in_view > 0.5) e.xyz *= 1.0 + u_view_bias;
    gl_Position = u_proj * e;
}
