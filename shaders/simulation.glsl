#version 430 core
// The forward model on the GPU (vrcorrect.forward.what_the_eye_sees): the eye's kernel K
// (cones x primaries), mapped back to the display's primaries by A^-1 (A = the kernel's sums),
// as one 3x3 bank A^-1 K run separably (filter_bank.glsl) with black outside the image, then
// clipped to the gamut. Previews "what the eye sees". Define BORDER_ZERO when compiling.
#include "srgb.glsl"

#if defined COMPUTE_SHADER
#include "filter_bank.glsl"

#if defined PASS_COLS
vec3 combine(vec3 filtered, vec3 target) {
    return clamp(filtered, 0.0, 1.0);
}
#endif
#endif
