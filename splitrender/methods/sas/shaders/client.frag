#version 430
// Bilinear lookup of the pre-shaded atlas; alpha 1 marks covered pixels (0 = hole).
uniform sampler2D u_atlas;
in vec2 v_uv;
layout(location = 0) out vec4 f_color;
void main() { f_color = vec4(texture(u_atlas, v_uv).rgb, 1.0); }
