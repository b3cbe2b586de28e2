#version 430
// Scene-wide triangle index + 1 (0 = background); the CPU maps triangles to patches.
uniform uint u_tri_base;
layout(location = 0) out uint f_id;
void main() { f_id = u_tri_base + uint(gl_PrimitiveID) + 1u; }
