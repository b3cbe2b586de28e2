#version 430
// Fragment of a warped splat or quad: colour with coverage in alpha, and the depth
// (metres, current view) that hole filling compares.
flat in vec3 g_color;
flat in float g_depth;
uniform sampler2D u_cover;    // coverage (alpha) of the view nearest the display pose
uniform int u_holes_only;     // 1: draw only where that view left a hole
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    if (u_holes_only == 1 && texelFetch(u_cover, ivec2(gl_FragCoord.xy), 0).a > 0.0) discard;
    f_color = vec4(g_color, 1.0);
    f_depth = g_depth;
}
