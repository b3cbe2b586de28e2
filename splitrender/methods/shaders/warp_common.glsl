// Shared per-pixel warp of the depth-image warping method (warp.py).
// One vertex per reference pixel (gl_VertexID = y * width + x, y from the top row).
// A pixel with view-space depth z (metres, 0 = background) and object id i is
// unprojected in the reference camera and moved by the object's 4x4 warp matrix
//   M_i = P_cur * V_cur * O_i(t) * O_i(ref)^-1 * V_ref^-1
// (fetched from u_mats with four texel reads), i.e. the paper's single matrix per
// object with the reference projection's inverse applied analytically.
uniform sampler2D u_color;    // reference colour, RGB8, texel row 0 = top row
uniform sampler2D u_depth;    // reference depth, R32F metres, 0 = background
uniform usampler2D u_ids;     // reference object ids, R16UI, 0 = background
uniform sampler2D u_mats;     // RGBA32F, 5 texels per id: columns of M_i, then (dynamic, 0, 0, 0)
uniform ivec2 u_ref_size;     // reference image size, pixels
uniform vec2 u_tan_half;      // tan(fov_x / 2), tan(fov_y / 2) of the reference camera
uniform vec2 u_out_size;      // display size, pixels
uniform vec2 u_proj_zz;       // current projection P[2][2], P[2][3]
uniform float u_bias_rel;     // relative depth bias of this view (secondary views lose ties)
uniform float u_disc;         // relative depth step treated as a discontinuity

ivec2 pixel_of(int vid) { return ivec2(vid % u_ref_size.x, vid / u_ref_size.x); }

float ref_depth(ivec2 p) { return texelFetch(u_depth, clamp(p, ivec2(0), u_ref_size - 1), 0).r; }
uint ref_id(ivec2 p) { return texelFetch(u_ids, clamp(p, ivec2(0), u_ref_size - 1), 0).r; }

mat4 warp_matrix(uint id) {
    int r = int(id);
    return mat4(texelFetch(u_mats, ivec2(0, r), 0), texelFetch(u_mats, ivec2(1, r), 0),
                texelFetch(u_mats, ivec2(2, r), 0), texelFetch(u_mats, ivec2(3, r), 0));
}
bool is_dynamic(uint id) { return texelFetch(u_mats, ivec2(4, int(id)), 0).x > 0.5; }

// Reference camera-space point for a (possibly fractional) pixel position and depth;
// background (z <= 0) becomes the direction at infinity (w = 0).
vec4 unproject(vec2 pc, float z) {
    vec2 ndc = vec2(pc.x / float(u_ref_size.x) * 2.0 - 1.0, 1.0 - pc.y / float(u_ref_size.y) * 2.0);
    vec3 dir = vec3(ndc * u_tan_half, -1.0);
    return z > 0.0 ? vec4(dir * z, 1.0) : vec4(dir, 0.0);
}

// Clip position of a warped point, with background pinned to the far plane and the view's depth bias.
vec4 warp_clip(mat4 M, vec2 pc, float z) {
    vec4 c = M * unproject(pc, z);
    if (z <= 0.0) {
        c.z = c.w * 0.999999;
    } else if (u_bias_rel > 0.0) {
        c.z = -u_proj_zz.x * c.w + u_proj_zz.y / (1.0 + u_bias_rel);
    }
    return c;
}

// Display pixel position (y up) of a clip position.
vec2 to_screen(vec4 c) { return (c.xy / c.w * 0.5 + 0.5) * u_out_size; }

bool discontinuous(float za, uint ia, float zb, uint ib) {
    if ((za <= 0.0) != (zb <= 0.0)) return true;
    if (za <= 0.0) return false;
    if (ia != ib && (is_dynamic(ia) || is_dynamic(ib))) return true;
    return abs(za - zb) > u_disc * min(za, zb);
}

// Depth of the neighbour at p + d for derivative estimates: its own depth where the
// surface continues, else -1 (invalid).
float neighbour_depth(ivec2 p, ivec2 d, float z, uint id) {
    ivec2 q = p + d;
    if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, u_ref_size))) return -1.0;
    float zq = ref_depth(q);
    return discontinuous(z, id, zq, ref_id(q)) ? -1.0 : zq;
}

// Jacobian of the warp in display pixels per reference pixel (columns: d/dx, d/dy),
// from central differences of warped neighbours (one-sided at discontinuities, as in the
// paper's depth-gradient form: a missing neighbour falls back to the local plane).
mat2 warp_jacobian(mat4 M, ivec2 p, float z, uint id, vec2 s0) {
    vec2 pc = vec2(p) + 0.5;
    vec2 col[2];
    for (int a = 0; a < 2; ++a) {
        ivec2 d = a == 0 ? ivec2(1, 0) : ivec2(0, 1);
        float zp = neighbour_depth(p, d, z, id);
        float zm = neighbour_depth(p, -d, z, id);
        vec2 sp, sm;
        float span = 2.0;
        if (z <= 0.0) { zp = 0.0; zm = 0.0; }
        if (zp < 0.0 && zm < 0.0) { zp = z; zm = z; }
        if (zp < 0.0) { sp = s0; span = 1.0; } else { sp = to_screen(warp_clip(M, pc + vec2(d), zp)); }
        if (zm < 0.0) { sm = s0; span = 1.0; } else { sm = to_screen(warp_clip(M, pc - vec2(d), zm)); }
        col[a] = (sp - sm) / span;
    }
    return mat2(col[0], col[1]);
}
