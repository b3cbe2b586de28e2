#version 430
// Sample gathering (paper sections 3.2-3.3): every tessellator vertex is a shading
// thread.  It finds its sample, shades it with the ground truth's shading code and
// writes the texel(s) straight into the atlas; the rasteriser does not run.
// Mirrors splitrender/methods/tss/layout.py (lp_positions, os_linear_id, os_row_lengths).
// point_mode and a position outside the clip volume: the tessellator's vertices become points that the clipper
// rejects before primitive assembly.  The shading and the stores are the same; llvmpipe's draw module otherwise
// assembled every tessellated triangle and, per flush of its vertex buffer, walked every vertex of the draw (a cost
// that grows with the square of one draw's samples: the duck's one object took 2x the shading itself).
layout(triangles, equal_spacing, ccw, point_mode) in;
in vec3 c_world[];
in vec3 c_normal[];
in vec2 c_uv[];
in vec4 c_tangent[];
in float c_depth[];
patch in vec4 p_info;
patch in vec4 p_o0;
patch in vec4 p_o1;
layout(rgba8, binding = 0) uniform writeonly image2D u_atlas;
layout(std430, binding = 1) buffer Counters { uint n_shaded; };
uniform vec3 u_eye;
uniform float u_lp_inset;  // L-packing: the lattice moved off the triangle's edges (layout.lp_inset_offset; 0: off)
uniform int u_single_px;   // single texels fill a cell this many texels square (layout.single_origins)
#include "tss_gather.glsl"
// The sample an invocation shades (oversampling: from its linear thread id), and whether it shades one.
bool os_sample(vec3 B, int l, out vec3 Bs, out ivec2 at) {
    float fl = float(l);
    float bmin = min(B.x, min(B.y, B.z));
    int k = int(round(bmin * 1.5 * fl));
    int n = l - 2 * k;
    int id = 3 * k * (l - k + 1);
    if (n > 0) {
        float d = float(k) * 2.0 / (3.0 * fl);
        int e = -1, j = 0;
        for (int ee = 0; ee < 3; ++ee) {
            int jj = int(round((B[(ee + 1) % 3] - d) * fl));
            if (e < 0 && abs(B[(ee + 2) % 3] - d) < 1.0 / (6.0 * fl) && jj < n && jj >= 0) { e = ee; j = jj; }
        }
        if (e < 0) return false;
        id += e * n + j;
    }
    return os_staircase(id, Bs, at);
}

void main() {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);   // outside: culled (see the layout above)
    vec3 B = gl_TessCoord;
    int kind = int(p_info.x + 0.5);
    int l = int(p_info.y + 0.5);
    g_lod = p_info.w;
    // Every kind first finds its sample; the shading runs once, outside every branch and loop: in SIMD
    // execution (llvmpipe, GPU warps) a shade inside a divergent branch or loop runs once per path taken.
    vec3 Bs = B;
    ivec2 at = ivec2(p_o0.xy);
    bool valid = true;
    if (kind == 0) {                       // one texel: the centroid, by the first corner's thread
        valid = B.x > 0.5;
        Bs = vec3(1.0 / 3.0);
    } else if (kind == 2) {
        valid = os_sample(B, l, Bs, at);
    } else if (u_lp_inset > 0.0) {         // shaded off the edges, stored where the edge lattice would be
        float d0 = u_lp_inset / (3.0 * float(l + 1));
        Bs = d0 + (1.0 - 3.0 * d0) * B;
    }
    if (!valid) return;
    vec3 c = shade_at(Bs);
    if (kind == 0) {                       // the texel's cell, u_single_px square
        for (int k = 0; k < u_single_px * u_single_px; ++k)
            imageStore(u_atlas, at + ivec2(k % u_single_px, k / u_single_px), vec4(c, 1.0));
        return;
    }
    if (kind == 2) {
        imageStore(u_atlas, at, vec4(c, 1.0));
        return;
    }
    // L-packing: every tip block the sample lies in or borders, folded at the diagonal
    int D = (l + 2) / 2 + (l & 1);
    for (int t = 0; t < 3; ++t) {
        int a = (t + 1) % 3, q = (t + 2) % 3;
        for (int side = 0; side < 2; ++side) {
            int s = side == 0 ? a : q;
            int m = side == 0 ? q : a;
            bool ok = side == 0 ? B[m] <= B[s] + EPS : B[m] < B[s] - EPS;
            int r = int(round(B[m] * 1.5 * float(l)));
            int col = int(round((B[s] + 0.5 * B[m]) * float(l)));
            if (!ok || col > D - 1 || B[m] > B[t] + EPS) continue;
            if (side == 0) store(tip_origin(t), col, r, c);
            else store(tip_origin(t), r, col, c);
            // odd levels leave each block's far corner empty and no tap reads it: a copy of its neighbour there
            // spares the codec a black texel (and its chroma) inside the block
            if (side == 0 && (l & 1) == 1 && col == D - 1 && r == D - 2) store(tip_origin(t), D - 1, D - 1, c);
        }
    }
}
