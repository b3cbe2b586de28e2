#version 430
// Patch-ID pass of the PVS (paper section 3.1): geometry only, depth tested.
in vec3 in_position;
uniform mat4 u_model;
uniform mat4 u_view;
uniform mat4 u_proj;
void main() { gl_Position = u_proj * u_view * u_model * vec4(in_position, 1.0); }
