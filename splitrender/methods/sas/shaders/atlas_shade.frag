#version 430
// Same surface shading as the ground truth (forward.frag), evaluated per atlas texel
// in object space; view-dependent terms use the predicted eye position.  Textures are
// filtered for the display's footprint, not the atlas texel's: each texel's texture
// gradients are those a forward render at the reference view (u_view_proj) takes per
// display pixel, d(uv)/d(screen) = d(uv)/d(atlas) * inverse(d(screen)/d(atlas)), both
// from the texel's neighbours; so the pre-filtered atlas is what a mip-mapped forward
// render shows, also across a large patch seen in perspective.  Where the reference
// view does not see the texel (behind the eye, edge-on) the gradients fall back to the
// atlas texel's scaled by v_footprint (block texels per display pixel along atlas x and
// y, >= 1).
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_tangent;
flat in vec4 v_rect;
flat in vec2 v_footprint;
uniform mat4 u_view_proj;
uniform vec2 u_viewport;   // display pixels
vec2 g_duv_dx, g_duv_dy;   // texture-coordinate gradients per display pixel, taken before any discard
#define ALBEDO_LOOKUP(uv) textureGrad(u_albedo, uv, g_duv_dx, g_duv_dy)
#include "shading.glsl"
uniform vec3 u_eye;
layout(location = 0) out vec4 f_color;
#ifdef SHADOW_CACHE
// The shadow factor cache (SasConfig.reuse_shadow): the loader renames shading.glsl's shadow_factor to
// shadow_factor_lookup (SasProducer.shade_programs); each texel's factor goes to attachment 1, and a block
// whose factor cannot have changed reads it back from last frame's cache (SHADOW_CACHE 2) instead of taking
// the 2 x 9 shadow-map taps (SHADOW_CACHE 1).
layout(location = 1) out float f_shadow;
uniform sampler2D u_shadow_cache;
float g_shadow = 1.0;
float shadow_factor(vec3 world_pos, vec3 n) {
#if SHADOW_CACHE == 2
    g_shadow = texelFetch(u_shadow_cache, ivec2(gl_FragCoord.xy), 0).r;
#else
    g_shadow = shadow_factor_lookup(world_pos, n);
#endif
    return g_shadow;
}
#endif
void main() {
    vec2 ux = dFdx(v_uv), uy = dFdy(v_uv);                       // per atlas texel
    vec4 c = u_view_proj * vec4(v_world, 1.0);
    vec2 s = c.xy / max(abs(c.w), 1e-6) * 0.5 * u_viewport;        // display pixels
    vec2 sx = dFdx(s), sy = dFdy(s);                                // display pixels per atlas texel
    float det = sx.x * sy.y - sy.x * sx.y;
    if (c.w > 1e-3 && abs(det) > 1e-6) {
        mat2 g = mat2(ux, uy) * inverse(mat2(sx, sy));              // columns: d(uv)/d(screen x), d(uv)/d(screen y)
        g_duv_dx = g[0];
        g_duv_dy = g[1];
    } else {
        g_duv_dx = ux * v_footprint.x;
        g_duv_dy = uy * v_footprint.y;
    }
    // shade() reads the maps at u_uv_transform * uv (KHR_texture_transform): the gradients go through its linear part
    g_duv_dx = mat2(u_uv_transform) * g_duv_dx;
    g_duv_dy = mat2(u_uv_transform) * g_duv_dy;
    vec2 p = gl_FragCoord.xy;
    if (p.x < v_rect.x || p.y < v_rect.y || p.x > v_rect.x + v_rect.z || p.y > v_rect.y + v_rect.w) discard;
    vec3 n = normalize(v_normal);
    if (dot(n, u_eye - v_world) < 0.0) n = -n;
    f_color = vec4(shade(v_world, n, v_tangent, v_uv, u_eye), 1.0);
#ifdef SHADOW_CACHE
    f_shadow = g_shadow;
#endif
}
