#version 430 core
// The per-frame blend weight of the wiener correction, on the GPU (vrcorrect.solvers.wiener), as
// vrcorrect.solvers.guard_weight(<r0, Kd>, <Kd, Kd>) computes it on the CPU:
// beta = clamp(-<r0, Kd> / <Kd, Kd>, 0, 1) (0 where <Kd, Kd> = 0), r0 = K t - T t (the uncorrected
// retinal residual), Kd = K (clip(F t) - t), sums over the image and the three cones: the weight
// that minimises the true objective, so the result is never worse than no correction. The third
// sum, <r0, r0>, gives the blended frame's objective as a fraction of the uncorrected one (read
// back by the CPU).
// SOLUTION (the projected-gradient guard): u_kd holds the residual K x - T of a solution x and
// u_delta holds x itself, so Kd = (K x - T) - r0 and d = x - t. Passes (define one):
//   PARTIAL  per 16x16 workgroup: the three sums -> u_partials[group]
//   FINAL    one workgroup adds the partials -> blend_beta (read by fft_filter.glsl's COMBINE)
//   APPLY    u_out = t + beta * d
#if defined COMPUTE_SHADER
layout(std430, binding = 3) buffer Blend { float blend_beta; float blend_sums[3]; };
layout(std430, binding = 4) buffer Partials { vec4 u_partials[]; };

#if defined PARTIAL
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_r0;          // (H, W) residual r0 (cones in .rgb)
uniform sampler2D u_kd;          // (H, W) K d (SOLUTION: K x - T)
shared vec4 sums[256];
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_r0, 0);
    vec4 s = vec4(0.0);
    if (p.x < size.x && p.y < size.y) {
        vec3 r = texelFetch(u_r0, p, 0).rgb;
        vec3 k = texelFetch(u_kd, p, 0).rgb;
#if defined SOLUTION
        k -= r;
#endif
        s = vec4(dot(r, k), dot(k, k), dot(r, r), 0.0);
    }
    uint i = gl_LocalInvocationIndex;
    sums[i] = s;
    barrier();
    for (uint stride = 128u; stride > 0u; stride >>= 1u) {
        if (i < stride) sums[i] += sums[i + stride];
        barrier();
    }
    if (i == 0u) u_partials[gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x] = sums[0];
}
#endif

#if defined FINAL
layout(local_size_x = 256) in;
uniform int u_count;
shared vec4 sums[256];
#include "guard.glsl"
void main() {
    uint i = gl_LocalInvocationIndex;
    vec4 total = guard_sum_partials(i, u_count);
    if (i == 0u) {
        blend_sums[0] = total.x;
        blend_sums[1] = total.y;
        blend_sums[2] = total.z;
        blend_beta = total.y > 0.0 ? clamp(-total.x / total.y, 0.0, 1.0) : 0.0;
    }
}
#endif

#if defined APPLY
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_linear_in;
uniform sampler2D u_delta;
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_linear_in, 0);
    if (p.x >= size.x || p.y >= size.y) return;
    vec3 t = texelFetch(u_linear_in, p, 0).rgb;
    vec3 d = texelFetch(u_delta, p, 0).rgb;
#if defined SOLUTION
    d -= t;
#endif
    imageStore(u_out, p, vec4(t + blend_beta * d, 1.0));
}
#endif
#endif
