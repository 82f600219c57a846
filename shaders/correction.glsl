#version 430 core
// The GLSL fallback of the wiener correction (vrcorrect.solvers.wiener): the eye's regularised
// inverse F, designed on the CPU and run as a separable low-rank bank (filter_bank.glsl) with
// mirrored borders, then x = t + beta * (clamp(F t, 0, 1) - t) in linear light.
// Compute passes: PASS_DECODE, PASS_ROWS, PASS_COLS (see filter_bank.glsl).
#include "srgb.glsl"

#if defined COMPUTE_SHADER
#include "filter_bank.glsl"

#if defined PASS_COLS
uniform float u_beta;                   // blend weight of the correction, in [0, 1]
vec3 combine(vec3 filtered, vec3 target) {
    return target + u_beta * (clamp(filtered, 0.0, 1.0) - target);
}
#endif
#endif
