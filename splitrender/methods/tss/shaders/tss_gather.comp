#version 430
// The paper's figure 16 comparison: oversampled triangles gathered by a compute shader with a fixed
// block size (one work group per triangle, its threads striding over the triangle's samples) instead of
// threads spawned by the tessellator.  Same sample layout and shading (tss_gather.glsl); only the
// benchmark uses it (benchmarks/bench_tss_gather.py).  BLOCK is defined by the loader.
layout(local_size_x = BLOCK) in;
// per triangle 19 vec4: world corners [3], normals [3], (uv, view depth) [3], tangents [3], info, o0, o1
layout(std430, binding = 2) readonly buffer Tris { vec4 tris[]; };
layout(rgba8, binding = 0) uniform writeonly image2D u_atlas;
layout(std430, binding = 1) buffer Counters { uint n_shaded; };
uniform vec3 u_eye;
uniform int u_first;   // first triangle of this dispatch (one dispatch per object: its material)
vec3 c_world[3];
vec3 c_normal[3];
vec2 c_uv[3];
vec4 c_tangent[3];
float c_depth[3];
vec4 p_info;
vec4 p_o0;
vec4 p_o1;
#include "tss_gather.glsl"
void main() {
    int k = 19 * (u_first + int(gl_WorkGroupID.x));
    for (int i = 0; i < 3; ++i) {
        c_world[i] = tris[k + i].xyz;
        c_normal[i] = tris[k + 3 + i].xyz;
        c_uv[i] = tris[k + 6 + i].xy;
        c_depth[i] = tris[k + 6 + i].z;
        c_tangent[i] = tris[k + 9 + i];
    }
    p_info = tris[k + 12];
    p_o0 = tris[k + 13];
    p_o1 = tris[k + 14];
    g_lod = p_info.w;
    int total = int(p_o1.w + 0.5);
    for (int id = int(gl_LocalInvocationID.x); id < total; id += BLOCK) {
        vec3 Bs;
        ivec2 at;
        if (os_staircase(id, Bs, at)) imageStore(u_atlas, at, vec4(shade_at(Bs), 1.0));
    }
}
