#version 430
// Bilinear lookup of the pre-shaded atlas, clamped to the block's texel centres so no
// tap reads a neighbouring block; alpha 1 marks covered pixels (0 = hole).
uniform sampler2D u_atlas;
in vec2 v_uv;
flat in vec4 v_clamp;
layout(location = 0) out vec4 f_color;
void main() { f_color = vec4(texture(u_atlas, clamp(v_uv, v_clamp.xy, v_clamp.zw)).rgb, 1.0); }
