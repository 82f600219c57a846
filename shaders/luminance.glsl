#version 430 core
// The frame's light for the viewing pupil (vrcorrect.runtime.strategies.base.LuminanceMeter): each
// 16 x 16 work group sums the luminance w . rgb of its pixels of the decoded linear frame (w: the
// display's luminance weights, white = 1) into one float of u_partials; the CPU adds the groups'
// sums, two frames later, and divides by the pixel count.
#if defined COMPUTE_SHADER
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_linear;
uniform vec3 u_weights;
uniform ivec2 u_size;
layout(std430, binding = 0) writeonly buffer Partials { float u_partials[]; };
shared float sums[256];
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    uint i = gl_LocalInvocationIndex;
    sums[i] = all(lessThan(p, u_size)) ? dot(texelFetch(u_linear, p, 0).rgb, u_weights) : 0.0;
    barrier();
    for (uint stride = 128u; stride > 0u; stride >>= 1u) {
        if (i < stride) sums[i] += sums[i + stride];
        barrier();
    }
    if (i == 0u) u_partials[gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x] = sums[0];
}
#endif
