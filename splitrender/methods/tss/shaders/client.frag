#version 430
// Per fragment (paper section 3.2 "Decoding"): object-space barycentrics, inverse
// perspective encoding (eq. 5), the L-packing or oversampling layout, one bilinear tap.
in vec3 v_bary;
flat in vec3 v_zref;
flat in vec4 v_info;
flat in vec4 v_o0;
flat in vec4 v_o1;
uniform sampler2D u_atlas;
uniform vec2 u_atlas_size;
uniform int u_single_px;    // side of a single texel's cell (layout.single_origins)
uniform int u_os_centred;   // oversampling grid: 1 cell centres, taps clamped to each row (layout.os_centred_taps)
uniform float u_lp_inset;   // L-packing lattice moved off the edges (layout.lp_inset_offset; 0: the paper's)
uniform int u_lp_cubic;     // L-packing off the diagonal: Catmull-Rom over 4x4 texels of the point's side (lp_filter)
layout(location = 0) out vec4 f_color;

vec4 catmull_rom(float t) {   // weights of the taps at -1, 0, 1, 2
    float t2 = t * t, t3 = t2 * t;
    return vec4(-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2);
}

// one side of a tip block's diagonal is an affine lattice (x along a ring's edge, y the ring): Catmull-Rom over the
// 4x4 texels around xy, each tap clamped to the block and to the point's side of the diagonal (x >= y on side a),
// so a tap never reads the mirrored side or a neighbouring block
vec3 lp_cubic(ivec2 o, vec2 xy, bool side_a, int Dm) {
    ivec2 i0 = ivec2(floor(xy));
    vec2 f = xy - vec2(i0);
    vec4 wx = catmull_rom(f.x), wy = catmull_rom(f.y);
    vec3 acc = vec3(0.0);
    for (int j = 0; j < 4; ++j) {
        vec3 row = vec3(0.0);
        for (int i = 0; i < 4; ++i) {
            ivec2 t = clamp(i0 + ivec2(i - 1, j - 1), ivec2(0), ivec2(Dm));
            if (side_a) t.x = max(t.x, t.y); else t.y = max(t.y, t.x);
            row += wx[i] * texelFetch(u_atlas, o + t, 0).rgb;
        }
        acc += wy[j] * row;
    }
    return clamp(acc, 0.0, 1.0);
}

vec2 tip_origin(int t) { return t == 0 ? v_o0.xy : (t == 1 ? v_o0.zw : v_o1.xy); }

void main() {
    vec3 b = max(v_bary, vec3(0.0));
    b /= (b.x + b.y + b.z);
    vec3 B = b;
    if (v_info.z > 0.5) {            // eq. 5: back to the reference view's screen-space barycentrics
        vec3 q = b * max(v_zref, vec3(1e-4));
        B = q / (q.x + q.y + q.z);
    }
    int kind = int(v_info.x + 0.5);
    vec2 p;
    if (kind == 0) {                 // the cell's centre: a u_single_px square cell is averaged
        p = v_o0.xy + 0.5 * float(u_single_px);
    } else if (kind == 1) {
        // each side of a tip block's diagonal is an affine lattice of its own (rows are rings); a bilinear tap on
        // a diagonal cell would read one sample of the mirrored side, a third of a sample step off: there, and in
        // the innermost ring of odd levels, which holds no row, interpolate linearly on the three samples around
        // the point instead (layout.lp_reconstruct; exact for linear shading)
        float l = v_info.y;
        if (u_lp_inset > 0.0) {
            float d0 = u_lp_inset / (3.0 * (l + 1.0));
            B = (B - d0) / (1.0 - 3.0 * d0);   // the lattice's coordinates: below 0 by up to half a ring, extrapolated
        }
        int li = int(l + 0.5), k = li / 2;
        int t = B.x >= B.y && B.x >= B.z ? 0 : (B.y >= B.z ? 1 : 2);
        int a = (t + 1) % 3, q = (t + 2) % 3;
        bool side_a = B[a] >= B[q];
        float s = side_a ? B[a] : B[q];
        float m = side_a ? B[q] : B[a];
        ivec2 o = ivec2(tip_origin(t));
        int Dm = (li + 2) / 2 + (li & 1) - 1;
        // (inset level 1: its three samples everywhere, the block's fourth texel is no sample to extrapolate with)
        if ((li & 1) == 1 && (m * 1.5 * l > float(k) || (u_lp_inset > 0.0 && li == 1))) {
            float d = 2.0 * float(k) / (3.0 * l);
            vec3 w = (vec3(B[t], B[a], B[q]) - d) / (1.0 - 3.0 * d);
            f_color = vec4(w.x * texelFetch(u_atlas, o + ivec2(k, k), 0).rgb + w.y * texelFetch(u_atlas, o + ivec2(k + 1, k), 0).rgb
                           + w.z * texelFetch(u_atlas, o + ivec2(k, k + 1), 0).rgb, 1.0);
            return;
        }
        float r = m * 1.5 * l;
        float c = (s + 0.5 * m) * l;
        vec2 xy = side_a ? vec2(c, r) : vec2(r, c);
        ivec2 i0 = ivec2(floor(xy));
        if (u_lp_inset > 0.0) {
            // the outer ring lies inside the triangle: the lattice's edge cell, bilinear (or the diagonal cell's
            // three samples), extrapolated past it; with lp_filter cubic the Catmull-Rom at the point moved onto
            // the lattice plus the edge cell's linear step to the point (layout.lp_inset_offset)
            i0 = clamp(i0, ivec2(0), ivec2(max(Dm - 1, 0)));
            vec2 f = xy - vec2(i0);
            ivec2 i1 = min(i0 + 1, ivec2(Dm));
            vec3 c00 = texelFetch(u_atlas, o + i0, 0).rgb, c11 = texelFetch(u_atlas, o + i1, 0).rgb;
            vec3 v;
            if (u_lp_cubic != 0 && i0.x != i0.y) {
                vec2 xc = clamp(xy, vec2(0.0), vec2(float(Dm)));
                vec3 c10 = texelFetch(u_atlas, o + ivec2(i1.x, i0.y), 0).rgb, c01 = texelFetch(u_atlas, o + ivec2(i0.x, i1.y), 0).rgb;
                v = lp_cubic(o, xc, side_a, Dm) + (xy.x - xc.x) * (c10 - c00) + (xy.y - xc.y) * (c01 - c00);
            } else if (i0.x != i0.y)
                v = (1.0 - f.x) * (1.0 - f.y) * c00 + f.x * (1.0 - f.y) * texelFetch(u_atlas, o + ivec2(i1.x, i0.y), 0).rgb
                    + (1.0 - f.x) * f.y * texelFetch(u_atlas, o + ivec2(i0.x, i1.y), 0).rgb + f.x * f.y * c11;
            else
                v = side_a ? (1.0 - f.x) * c00 + (f.x - f.y) * texelFetch(u_atlas, o + ivec2(i1.x, i0.y), 0).rgb + f.y * c11
                           : (1.0 - f.y) * c00 + (f.y - f.x) * texelFetch(u_atlas, o + ivec2(i0.x, i1.y), 0).rgb + f.x * c11;
            f_color = vec4(clamp(v, 0.0, 1.0), 1.0);
            return;
        }
        if (i0.x != i0.y) {
            if (u_lp_cubic != 0) {
                f_color = vec4(lp_cubic(o, xy, side_a, Dm), 1.0);
                return;
            }
            p = vec2(o) + 0.5 + xy;
        } else {
            vec2 f = xy - vec2(i0);
            ivec2 i1 = min(i0 + 1, ivec2(Dm));
            vec3 c00 = texelFetch(u_atlas, o + i0, 0).rgb, c11 = texelFetch(u_atlas, o + i1, 0).rgb;
            vec3 v = f.x >= f.y ? (1.0 - f.x) * c00 + (f.x - f.y) * texelFetch(u_atlas, o + ivec2(i1.x, i0.y), 0).rgb + f.y * c11
                                : (1.0 - f.y) * c00 + (f.y - f.x) * texelFetch(u_atlas, o + ivec2(i0.x, i1.y), 0).rgb + f.x * c11;
            f_color = vec4(v, 1.0);
            return;
        }
    } else if (u_os_centred != 0) {
        // centred grid: two rows around the point, in each the two samples around its column,
        // clamped to the samples that row holds (its length as the server's os_row_lengths)
        float a = v_o0.w;
        int W1 = int(v_o1.x + 0.5), W2 = int(v_o1.y + 0.5), H = int(v_o1.z + 0.5), PW = int(v_o0.z + 0.5);
        float s = B.y + B.z * a;
        bool first = s <= a;
        float x = first ? (a > 0.0 ? (a - s) / a * float(W1) : 0.0) : (a < 1.0 ? (s - a) / (1.0 - a) * float(W2) : 0.0);
        int W = first ? W1 : W2;
        float yc = clamp(B.z * float(H) - 0.5, 0.0, float(H - 1));
        int j0 = int(floor(yc));
        int j1 = min(j0 + 1, H - 1);
        float fy = yc - float(j0);
        ivec2 o = ivec2(v_o0.xy);
        vec3 acc = vec3(0.0);
        for (int r = 0; r < 2; ++r) {
            int j = r == 0 ? j0 : j1;
            int n = max((W * (H - j) + H - 1) / H, 1);
            float xc = clamp(x - 0.5, 0.0, float(n - 1));
            int i0 = int(floor(xc));
            int i1 = min(i0 + 1, n - 1);
            float fx = xc - float(i0);
            ivec2 t0 = first ? o + ivec2(i0, j) : o + ivec2(PW - 1 - i0, H - 1 - j);
            ivec2 t1 = first ? o + ivec2(i1, j) : o + ivec2(PW - 1 - i1, H - 1 - j);
            vec3 row = mix(texelFetch(u_atlas, t0, 0).rgb, texelFetch(u_atlas, t1, 0).rgb, fx);
            acc += row * (r == 0 ? 1.0 - fy : fy);
        }
        f_color = vec4(acc, 1.0);
        return;
    } else {
        // the two right-triangle staircases: which side of the height's foot, then x from it
        float a = v_o0.w;
        float y = B.z * v_o1.z;
        float s = B.y + B.z * a;
        if (s <= a) p = v_o0.xy + 0.5 + vec2(a > 0.0 ? (a - s) / a * v_o1.x : 0.0, y);
        else p = v_o0.xy + 0.5 + vec2(v_o0.z - 1.0 - (a < 1.0 ? (s - a) / (1.0 - a) * v_o1.y : 0.0), v_o1.z - y);
    }
    f_color = vec4(texture(u_atlas, p / u_atlas_size).rgb, 1.0);
}
