#version 430
// Fragment of a warped splat or quad: colour with coverage in alpha, and the depth
// (metres, current view) that hole filling compares.
flat in vec3 g_color;
flat in float g_depth;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    f_color = vec4(g_color, 1.0);
    f_depth = g_depth;
}
