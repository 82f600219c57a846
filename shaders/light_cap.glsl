// The box's upper end at a texel whose target is t (a library for admm.glsl, admm_present.glsl,
// fovea_window.glsl and fovea_periphery.glsl): 1, or with LIGHT_CAP (a robust design) the light cap
// min(1, 2 t + LIGHT_CAP) (vrcorrect.solvers.problem.light_cap).  CAP_UNIFORM (with LIGHT_CAP
// u_cap_floor): the floor is the uniform u_cap_floor, so that a switch of design between a capped and
// an uncapped band changes a uniform, not the programs: LIGHT_CAP_FLOOR capped, 1 uncapped
// (min(1, 2 t + 1) = 1 for t >= 0).
#ifndef LIGHT_CAP_GLSL
#define LIGHT_CAP_GLSL
#if defined CAP_UNIFORM
uniform float u_cap_floor;
#endif
vec3 box_top(vec3 t) {
#if defined LIGHT_CAP
    return min(vec3(1.0), 2.0 * t + vec3(LIGHT_CAP));
#else
    return vec3(1.0);
#endif
}
#endif
