#version 430
// Rotational reprojection (asynchronous time warp): each display pixel looks up the
// reference frame through a homography H (display pixel -> reference pixel, both with
// a top-left origin, homogeneous).  Pixels that fall outside the reference frame are
// holes: alpha 0, filled black or with the nearest edge texel.
uniform sampler2D u_ref;
uniform vec2 u_ref_size;     // reference image size, pixels
uniform vec2 u_out_size;     // display size, pixels
uniform mat3 u_H;
uniform int u_fill_edge;     // 1: clamp to the reference edge, 0: black
out vec4 f_color;
void main() {
    vec2 px = vec2(gl_FragCoord.x, u_out_size.y - gl_FragCoord.y);
    vec3 h = u_H * vec3(px, 1.0);
    if (h.z <= 1e-6) { f_color = vec4(0.0); return; }
    vec2 q = h.xy / h.z;
    bool inside = all(greaterThanEqual(q, vec2(0.0))) && all(lessThanEqual(q, u_ref_size));
    if (!inside && u_fill_edge == 0) { f_color = vec4(0.0); return; }
    vec2 uv = clamp(q, vec2(0.5), u_ref_size - 0.5) / u_ref_size;
    f_color = vec4(texture(u_ref, uv).rgb, inside ? 1.0 : 0.0);
}
