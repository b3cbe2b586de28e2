#version 430
// Lookup of the pre-shaded atlas, never reading a neighbouring block: with u_bicubic a
// Catmull-Rom filter over 4x4 texels, each tap clamped to the block's texels (edge
// texels repeat); else one bilinear tap clamped to the block's texel centres.  Alpha 1
// marks covered pixels (0 = hole).
uniform sampler2D u_atlas;
uniform int u_bicubic;
in vec2 v_uv;
flat in vec4 v_clamp;   // the block's texel centres, normalised (x0, y0, x1, y1)
layout(location = 0) out vec4 f_color;

vec4 catmull_rom(float t) {   // weights of the taps at -1, 0, 1, 2
    float t2 = t * t, t3 = t2 * t;
    return vec4(-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2);
}

void main() {
    vec2 uv = clamp(v_uv, v_clamp.xy, v_clamp.zw);
    if (u_bicubic == 0) {
        f_color = vec4(texture(u_atlas, uv).rgb, 1.0);
        return;
    }
    vec2 size = vec2(textureSize(u_atlas, 0));
    vec2 p = uv * size - 0.5;            // texel index space, centres at integers
    vec2 i0 = floor(p);
    vec2 f = p - i0;
    ivec2 lo = ivec2(floor(v_clamp.xy * size)), hi = ivec2(floor(v_clamp.zw * size));
    vec4 wx = catmull_rom(f.x), wy = catmull_rom(f.y);
    vec3 acc = vec3(0.0);
    for (int j = 0; j < 4; ++j) {
        vec3 row = vec3(0.0);
        for (int i = 0; i < 4; ++i)
            row += wx[i] * texelFetch(u_atlas, clamp(ivec2(i0) + ivec2(i - 1, j - 1), lo, hi), 0).rgb;
        acc += wy[j] * row;
    }
    f_color = vec4(clamp(acc, 0.0, 1.0), 1.0);
}
