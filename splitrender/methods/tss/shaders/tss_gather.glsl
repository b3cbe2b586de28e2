// Sample gathering shared by the tessellation path (tss_shade.tese) and the compute-shader
// generator of the figure 16 benchmark (tss_gather.comp).  The including shader declares the
// triangle's corners c_world[3], c_normal[3], c_uv[3], c_tangent[3], c_depth[3], its layout
// p_info, p_o0, p_o1, the atlas image u_atlas and the Counters buffer, then includes this file.
float g_lod;              // the triangle's albedo mip level (the fallback)
bool g_grad = false;      // per-sample gradients found
vec2 g_dx, g_dy;          // d(uv)/d(display x, y) at the sample, seen from the reference view
uniform mat4 u_view_proj; // the reference view's projection * view (zero: per-triangle levels only)
uniform vec2 u_viewport;  // display pixels
uniform int u_os_centred; // oversampling grid: 1 cell centres (layout.os_row_lengths "centred"), 0 the paper's lattice
#define ALBEDO_LOOKUP(uv) (g_grad ? textureGrad(u_albedo, uv, g_dx, g_dy) : textureLod(u_albedo, uv, g_lod))
// the other maps with the same gradients (texture() here would read their level 0, unfiltered: the default scene's
// emissive sign aliased, 26 dB lossless at any rate); the fallback level is the albedo's, moved by the maps' size ratio
#define MAP_LOOKUP(tex, uv) (g_grad ? textureGrad(tex, uv, g_dx, g_dy) : textureLod(tex, uv, max(0.0, g_lod + log2(float(textureSize(tex, 0).x) / float(textureSize(u_albedo, 0).x)))))
#include "shading.glsl"
const float EPS = 1e-4;

// The texture gradients a forward render at the reference view takes at object-space barycentrics ``b``:
// uv is affine in b, the display position projective, d(uv)/d(screen) = d(uv)/d(b) * inverse(d(screen)/d(b)).
void sample_gradients(vec3 b) {
    vec4 c0 = u_view_proj * vec4(c_world[0], 1.0);
    vec4 e1 = u_view_proj * vec4(c_world[1], 1.0) - c0;
    vec4 e2 = u_view_proj * vec4(c_world[2], 1.0) - c0;
    vec4 c = c0 + b.y * e1 + b.z * e2;
    g_grad = false;
    if (c.w < 1e-3) return;
    vec2 s1 = (e1.xy * c.w - c.xy * e1.w) / (c.w * c.w) * 0.5 * u_viewport;
    vec2 s2 = (e2.xy * c.w - c.xy * e2.w) / (c.w * c.w) * 0.5 * u_viewport;
    float det = s1.x * s2.y - s2.x * s1.y;
    if (abs(det) < 1e-6) return;
    // shade() reads the maps at u_uv_transform * uv (KHR_texture_transform), so the gradients go through its linear
    // part too (TextureTransformTest scales two of its quads by 1.5: their mip level was 0.58 too fine)
    mat2 g = mat2(u_uv_transform) * mat2(c_uv[1] - c_uv[0], c_uv[2] - c_uv[0]) * inverse(mat2(s1, s2));
    g_dx = g[0];
    g_dy = g[1];
    g_grad = true;
}

// screen-space barycentrics at the reference view -> object-space ones (perspective, [MHAM08])
vec3 to_object(vec3 B) {
    if (p_info.z < 0.5) return B;
    vec3 z = vec3(max(c_depth[0], 1e-4), max(c_depth[1], 1e-4), max(c_depth[2], 1e-4));
    vec3 q = B / z;
    return q / (q.x + q.y + q.z);
}

vec3 shade_at(vec3 B) {
    vec3 b = to_object(B);
    vec3 world = b.x * c_world[0] + b.y * c_world[1] + b.z * c_world[2];
    vec3 n = b.x * c_normal[0] + b.y * c_normal[1] + b.z * c_normal[2];
    vec2 uv = b.x * c_uv[0] + b.y * c_uv[1] + b.z * c_uv[2];
    vec4 tg = vec4(b.x * c_tangent[0].xyz + b.y * c_tangent[1].xyz + b.z * c_tangent[2].xyz, c_tangent[0].w);
    sample_gradients(b);
    atomicAdd(n_shaded, 1u);
    return shade(world, n, tg, uv, u_eye);
}

void store(vec2 origin, int x, int y, vec3 c) {
    imageStore(u_atlas, ivec2(origin) + ivec2(x, y), vec4(c, 1.0));
}

vec2 tip_origin(int t) { return t == 0 ? p_o0.xy : (t == 1 ? p_o0.zw : p_o1.xy); }

// Oversampling sample ``id`` (0 .. samples - 1): its screen-space barycentrics and texel; false past the end.
bool os_staircase(int id, out vec3 Bs, out ivec2 at) {
    if (id < 0 || id >= int(p_o1.w + 0.5)) return false;
    // two right-triangle staircases (figure 8): x along the base from the foot, y up the height
    float a = p_o0.w;
    int W1 = int(p_o1.x + 0.5), W2 = int(p_o1.y + 0.5), H = int(p_o1.z + 0.5);
    bool centred = u_os_centred != 0;
    int rows = centred ? H : H + 1;
    int left = id, hf = -1, y = 0;
    for (int h2 = 0; h2 < 2 && hf < 0; ++h2) {
        int W = h2 == 0 ? W1 : W2;
        for (int yy = 0; yy < rows; ++yy) {
            int len = centred ? max((W * (H - yy) + H - 1) / H, 1) : (W * (H - max(yy - 1, 0))) / H + 2;
            if (left < len) { hf = h2; y = yy; break; }
            left -= len;
        }
    }
    if (hf < 0) return false;
    int x = left;
    float c = centred ? 0.5 : 0.0;
    vec3 foot = vec3(1.0 - a, a, 0.0);
    vec3 along = hf == 0 ? vec3(a, -a, 0.0) / float(W1) : vec3(-(1.0 - a), 1.0 - a, 0.0) / float(W2);
    Bs = foot + (float(x) + c) * along + (float(y) + c) / float(H) * vec3(-(1.0 - a), -a, 1.0);
    ivec2 o = ivec2(p_o0.xy);
    at = hf == 0 ? o + ivec2(x, y) : o + ivec2(int(p_o0.z + 0.5) - 1 - x, rows - 1 - y);
    return true;
}

