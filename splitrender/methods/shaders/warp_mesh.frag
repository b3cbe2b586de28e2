#version 430
// Fragment of the warped grid mesh: interpolated colour, coverage in alpha, depth in metres.
in vec3 g_color;
in float g_depth;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    f_color = vec4(g_color, 1.0);
    f_depth = g_depth;
}
