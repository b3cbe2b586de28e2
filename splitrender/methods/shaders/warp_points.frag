#version 430
// Fragment of a point splat (see warp_splat.frag).
flat in vec3 v_color;
flat in float v_depth;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    f_color = vec4(v_color, 1.0);
    f_depth = v_depth;
}
