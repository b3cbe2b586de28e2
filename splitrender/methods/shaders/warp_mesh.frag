#version 430
// Fragment of the warped grid mesh: interpolated colour, coverage in alpha, depth in metres.
in vec3 g_color;
in float g_depth;
uniform sampler2D u_cover;    // coverage (alpha) of the view nearest the display pose
uniform int u_holes_only;     // 1: draw only where that view left a hole
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    if (u_holes_only == 1 && texelFetch(u_cover, ivec2(gl_FragCoord.xy), 0).a > 0.0) discard;
    f_color = vec4(g_color, 1.0);
    f_depth = g_depth;
}
