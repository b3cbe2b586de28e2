#version 430
// Renderer.shade's pixel mask: the near plane written into the depth buffer where the mask is 0, so that an equal
// depth test fails there before the shading pass's fragment shader runs.
uniform sampler2D u_where;   // 1 where shading is wanted
void main() {
    if (texelFetch(u_where, ivec2(gl_FragCoord.xy), 0).r > 0.5) discard;
    gl_FragDepth = 0.0;
}
