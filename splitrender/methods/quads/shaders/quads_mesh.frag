#version 430
// Colour from the quad's own atlas pixels: the lookup is clamped to the texel centres of
// its rect, so bilinear filtering never mixes in a neighbouring quad.
// The centre view's guard (QuadStream): a fragment of a later view that the centre camera sees more than
// u_guard_front in front of the centre view's own surface is discarded (mesh.py's QuadMeshGL.set_guard).
in vec3 v_uvw;
flat in vec4 v_rect;
in float v_depth;
in vec3 v_world;
flat in float v_view;
uniform sampler2D u_atlas;
uniform vec2 u_atlas_size;
uniform int u_has_atlas;
uniform int u_atlas_alpha;     // 1: the atlas's alpha is the output's (the server's residual-error test: a mask)
#ifdef QUADS_GUARD
// compiled in only for a mesh with a guard (QuadStream): a shader that can discard has every fragment shaded before
// its depth test (llvmpipe), one without is depth-tested first (QUASAR's mesh draw ~1/3 less CPU, the same pixels)
uniform int u_has_guard;
uniform sampler2D u_guard;     // the centre view's mesh: view depth from the centre camera (0: none)
uniform mat4 u_guard_vp;
uniform mat4 u_guard_view;
uniform vec2 u_guard_size;
uniform float u_guard_front;
uniform float u_guard_reach;
#endif
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
#ifdef QUADS_GUARD
    if (u_has_guard == 1 && v_view > 0.5) {
        vec4 c = u_guard_vp * vec4(v_world, 1.0);
        if (c.w > 0.0) {
            vec2 px = (c.xy / c.w * 0.5 + 0.5) * u_guard_size;
            if (all(greaterThanEqual(px, vec2(0.0))) && all(lessThan(px, u_guard_size))) {
                float nearest = 1e30;    // the centre's nearest surface within u_guard_reach pixels
                for (int k = 0; k < 4; k++) {
                    vec2 o = vec2((k & 1) == 0 ? -u_guard_reach : u_guard_reach, k < 2 ? -u_guard_reach : u_guard_reach);
                    ivec2 t = clamp(ivec2(floor(px + o)), ivec2(0), ivec2(u_guard_size) - 1);
                    float z = texelFetch(u_guard, t, 0).r;
                    if (z > 0.0) nearest = min(nearest, z);
                }
                float zc = -(u_guard_view * vec4(v_world, 1.0)).z;
                if (nearest < 1e30 && zc < nearest * (1.0 - u_guard_front)) discard;
            }
        }
    }
#endif
    vec4 c = vec4(0.0, 0.0, 0.0, 1.0);
    if (u_has_atlas == 1) {
        vec2 uv = clamp(v_uvw.xy / v_uvw.z, v_rect.xy + 0.5, v_rect.zw - 0.5) / u_atlas_size;
        c = texture(u_atlas, uv);
    }
    f_color = vec4(c.rgb, u_atlas_alpha == 1 ? c.a : 1.0);
    f_depth = v_depth;
}
