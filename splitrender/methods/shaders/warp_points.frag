#version 430
// Fragment of a point splat (see warp_splat.frag).
flat in vec3 v_color;
flat in float v_depth;
uniform sampler2D u_cover;    // coverage (alpha) of the view nearest the display pose
uniform int u_holes_only;     // 1: draw only where that view left a hole
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    if (u_holes_only == 1 && texelFetch(u_cover, ivec2(gl_FragCoord.xy), 0).a > 0.0) discard;
    f_color = vec4(v_color, 1.0);
    f_depth = v_depth;
}
