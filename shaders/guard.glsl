// The guard's final reduction, shared by blend.glsl's FINAL and admm.glsl's GUARD_FINAL: one
// workgroup of 256 invocations adds the per-row or per-group partial sums (<r0, Kd>, <Kd, Kd>,
// <r0, r0>) of u_partials[0 .. count) into one vec4 (the order of the additions is fixed, so
// every caller gets the same bits). A library: #include "guard.glsl" after declaring the
// buffer u_partials (vec4[]) and `shared vec4 sums[256]`, in a compute stage with
// local_size_x = 256; call it from uniform control flow (it holds barriers).
#ifndef VRCORRECT_GUARD_GLSL
#define VRCORRECT_GUARD_GLSL

// The sum of u_partials[0 .. count), in every invocation (i: gl_LocalInvocationIndex).
vec4 guard_sum_partials(uint i, int count) {
    vec4 s = vec4(0.0);
    for (int k = int(i); k < count; k += 256) s += u_partials[k];
    sums[i] = s;
    barrier();
    for (uint stride = 128u; stride > 0u; stride >>= 1u) {
        if (i < stride) sums[i] += sums[i + stride];
        barrier();
    }
    return sums[0];
}

#endif
