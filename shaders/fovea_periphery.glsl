// The periphery of a foveated frame at a view texel (a library for fovea.glsl's CROP and COMPOSE and
// fovea_present.glsl): the target plus the coarse correction's change, upsampled bilinearly from the
// half-resolution level (u_pdelta, u_psize) to the view (u_full), clipped to [0, 1] (LIGHT_CAP: to
// min(1, 2 t + LIGHT_CAP), the light cap): the CPU twin's vrcorrect.solvers.foveated.FoveatedFrames
// with periphery "half" or "quarter".
#ifndef FOVEA_PERIPHERY_GLSL
#define FOVEA_PERIPHERY_GLSL
#include "light_cap.glsl"
uniform sampler2D u_pdelta;     // the change at half the view's resolution
uniform ivec2 u_psize;          // its size
uniform ivec2 u_full;           // the view's size
vec3 change_at(ivec2 q) { return texelFetch(u_pdelta, q, 0).rgb; }
#include "fovea_upsample.glsl"
vec3 periphery_shown(ivec2 p, vec3 t) { return clamp(t + upsampled(p, u_full, u_psize), vec3(0.0), box_top(t)); }
#endif
