#version 430
#include "shading.glsl"
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_tangent;
in float v_view_depth;
uniform vec3 u_eye;
uniform uint u_object_id;
uniform uint u_primitive_base;   // added to gl_PrimitiveID: a scene-wide triangle id
layout(location = 0) out vec4 f_color;
#ifdef SHADE_PASS
// The colour of a G-buffer already drawn (Renderer.shade): its depth buffer is bound with an equal test, so only the
// nearest fragments reach this shader; of those, only the one of the triangle that won the pixel is shaded (a
// fragment of another triangle at the same quantised depth would have lost the first pass's less-than test).
uniform usampler2D u_drawn_ids;  // the first pass's object and triangle ids
#else
layout(location = 1) out vec4 f_normal;   // world normal, facing the viewer
layout(location = 2) out uvec2 f_ids;     // object id, scene-wide triangle id + 1
layout(location = 3) out float f_depth;   // view-space depth along -Z, metres
uniform int u_peel_on;           // depth peeling: drop fragments at or in front of the previous layer
uniform sampler2D u_peel;        // the previous layer's view depth per pixel (inf: nothing behind it is kept)
uniform float u_peel_eps;        // relative gap a fragment must keep behind the previous layer
#endif
void main() {
    uvec2 ids = uvec2(u_object_id, u_primitive_base + uint(gl_PrimitiveID) + 1u);
#ifdef SHADE_PASS
    if (texelFetch(u_drawn_ids, ivec2(gl_FragCoord.xy), 0).xy != ids) discard;
#else
    if (u_peel_on == 1) {
        if (v_view_depth <= texelFetch(u_peel, ivec2(gl_FragCoord.xy), 0).r * (1.0 + u_peel_eps)) discard;
        if (dot(v_normal, u_eye - v_world) < 0.0) discard;   // a back face: its own front hides it from every eye
    }
#endif
    vec3 n = normalize(v_normal);
    if (dot(n, u_eye - v_world) < 0.0) n = -n;
#ifdef NO_COLOR
    f_color = vec4(0.0);   // a G-buffer without colour (Renderer.shade adds it)
#else
    f_color = vec4(shade(v_world, n, v_tangent, v_uv, u_eye), 1.0);
#endif
#ifndef SHADE_PASS
    f_normal = vec4(n, 0.0);
    f_ids = ids;
    f_depth = v_view_depth;
#endif
}
