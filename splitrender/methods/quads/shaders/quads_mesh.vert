#version 430
// The layered quad mesh: world-space corners, homogeneous atlas pixel coordinates (u z, v z, z)
// with z the source camera's depth, the quad's atlas rect.
in vec3 in_pos;
in vec3 in_uvw;
in vec4 in_rect;
uniform mat4 u_vp;
uniform mat4 u_view;
out vec3 v_uvw;
flat out vec4 v_rect;
out float v_depth;
void main() {
    v_uvw = in_uvw;
    v_rect = in_rect;
    v_depth = -(u_view * vec4(in_pos, 1.0)).z;
    gl_Position = u_vp * vec4(in_pos, 1.0);
}
