#version 430
// EVS on the GPU: per pixel of the patch-ID buffer, one atomic increment of its patch's
// pixel count (paper section 3.1's projected areas), so no ID buffer is read back.
layout(local_size_x = 16, local_size_y = 16) in;
layout(r32ui, binding = 0) uniform readonly uimage2D u_ids;       // triangle id + 1 (0 = background)
layout(std430, binding = 1) readonly buffer Lookup { uint u_tri_patch[]; };   // triangle id + 1 -> patch id + 1
layout(std430, binding = 2) buffer Counts { uint u_counts[]; };   // pixels per patch, this sample
uniform ivec2 u_size;
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_size.x || p.y >= u_size.y) return;
    uint id = imageLoad(u_ids, p).x;
    if (id == 0u) return;
    uint patch_id = u_tri_patch[id];
    if (patch_id != 0u) atomicAdd(u_counts[patch_id - 1u], 1u);
}
