#version 430 core
// A foveated frame's two passes of its own (vrcorrect.runtime.strategies.foveated; the CPU twin is
// vrcorrect.solvers.foveated, which states the mathematics). GL texel coordinates, rows bottom first.
//   CROP     the sub-image (the window around the gaze and its ring) out of the view's decoded
//            target, into the ADMM strategy's target texture
//   COMPOSE  the view shown (fovea_window.glsl), into a float image: the previews' and read-backs'
//            (a frame's own present draws it sRGB-encoded in one pass: fovea_present.glsl)
#if defined COMPUTE_SHADER
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_t;          // the view's decoded target
uniform ivec2 u_origin;         // the sub-image's first texel in the view

#if defined CROP
uniform ivec2 u_size;           // the sub-image's size
layout(IMG_FMT, binding = 1) writeonly uniform image2D u_sub;
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_size.x || p.y >= u_size.y) return;
    imageStore(u_sub, p, texelFetch(u_t, u_origin + p, 0));
}
#endif

#if defined COMPOSE
uniform sampler2D u_q;          // the sub-image's state q (its grid; the sub-image at the origin)
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;
#include "fovea_window.glsl"

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_view.x || p.y >= u_view.y) return;
    imageStore(u_out, p, vec4(fovea_shown(p), 1.0));
}
#endif
#endif
