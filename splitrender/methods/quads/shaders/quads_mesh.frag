#version 430
// Colour from the quad's own atlas pixels: the lookup is clamped to the texel centres of
// its rect, so bilinear filtering never mixes in a neighbouring quad.
in vec3 v_uvw;
flat in vec4 v_rect;
in float v_depth;
uniform sampler2D u_atlas;
uniform vec2 u_atlas_size;
uniform int u_has_atlas;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    vec3 c = vec3(0.0);
    if (u_has_atlas == 1) {
        vec2 uv = clamp(v_uvw.xy / v_uvw.z, v_rect.xy + 0.5, v_rect.zw - 0.5) / u_atlas_size;
        c = texture(u_atlas, uv).rgb;
    }
    f_color = vec4(c, 1.0);
    f_depth = v_depth;
}
