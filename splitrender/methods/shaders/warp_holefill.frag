#version 430
// Hole filling (paper, section 3.3, after Mark): a display pixel no warped fragment
// reached scans along the epipolar direction both ways and takes the farther of the
// two first covered samples (the background that the disocclusion uncovered).
// Alpha keeps the coverage (1 = warped sample, 0 = hole), so the hole mask survives.
uniform sampler2D u_warped;   // RGBA8, alpha = coverage
uniform sampler2D u_wdepth;   // R32F, depth in metres of the warped sample
uniform vec2 u_out_size;
uniform vec3 u_epipole;       // epipole of the primary reference camera, homogeneous display pixels (y up)
uniform int u_max_scan;       // pixels scanned in each direction
uniform int u_fill;           // 0: leave holes black
out vec4 f_color;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 w = texelFetch(u_warped, p, 0);
    if (w.a > 0.0) { f_color = vec4(w.rgb, 1.0); return; }
    if (u_fill == 0) { f_color = vec4(0.0); return; }
    vec2 pc = gl_FragCoord.xy;
    vec2 d = u_epipole.xy - pc * u_epipole.z;
    float n = length(d);
    d = n > 1e-6 ? d / n : vec2(1.0, 0.0);
    vec3 best = vec3(0.0);
    float best_depth = -1.0;
    for (int s = 0; s < 2; ++s) {
        vec2 dir = s == 0 ? d : -d;
        for (int k = 1; k <= u_max_scan; ++k) {
            ivec2 q = ivec2(floor(pc + dir * float(k)));
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, ivec2(u_out_size)))) break;
            vec4 c = texelFetch(u_warped, q, 0);
            if (c.a > 0.0) {
                float z = texelFetch(u_wdepth, q, 0).r;
                if (z > best_depth) { best_depth = z; best = c.rgb; }
                break;
            }
        }
    }
    f_color = vec4(best, 0.0);
}
