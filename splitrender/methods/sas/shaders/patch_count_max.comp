#version 430
// PVS accumulation on the GPU: the largest EVS area per patch over the samples so far;
// clears the per-sample counts for the next sample.
layout(local_size_x = 256) in;
layout(std430, binding = 2) buffer Counts { uint u_counts[]; };
layout(std430, binding = 3) buffer Acc { uint u_acc[]; };
uniform uint u_n;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= u_n) return;
    u_acc[i] = max(u_acc[i], u_counts[i]);
    u_counts[i] = 0u;
}
