#version 430 core
// A foveated frame's two passes of its own (vrcorrect.runtime.strategies.foveated; the CPU twin is
// vrcorrect.solvers.foveated, which states the mathematics). GL texel coordinates, rows bottom first.
//   CROP     the sub-image (the window around the gaze and its ring) out of the view's decoded
//            target, into the ADMM strategy's target texture
//   COMPOSE  the view shown (fovea_window.glsl), into a float image: the previews' and read-backs'
//            (a frame's own present draws it sRGB-encoded in one pass: fovea_present.glsl)
#if defined COMPUTE_SHADER
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_t;          // the view's decoded target (POOL, DELTA: the level's)
uniform ivec2 u_origin;         // the sub-image's first texel in the view

// A value as the strategy's textures hold it (16-bit floats rounded to nearest with HALF).
vec3 stored3(vec3 v) {
#if defined HALF
    return vec3(unpackHalf2x16(packHalf2x16(v.rg)), unpackHalf2x16(packHalf2x16(vec2(v.b, 0.0))).x);
#else
    return v;
#endif
}

#if defined CROP
uniform ivec2 u_size;           // the sub-image's size
layout(IMG_FMT, binding = 1) writeonly uniform image2D u_sub;
layout(IMG_FMT, binding = 2) writeonly uniform image2D u_hold;    // PERIPHERY: what the view shows there
#if defined PERIPHERY
#include "fovea_periphery.glsl"
#endif
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_size.x || p.y >= u_size.y) return;
    vec4 t = texelFetch(u_t, u_origin + p, 0);
    imageStore(u_sub, p, t);
#if defined PERIPHERY
    imageStore(u_hold, p, vec4(stored3(periphery_shown(u_origin + p, t.rgb)), 1.0));
#endif
}
#endif

// POOL: the 2x2 block means of an image (u_t, u_src_size) into the next level (u_dst_size), the
// blocks counted from the image's top-left corner with the last row or column repeated where the
// size is odd, as the CPU twin pools (vrcorrect.solvers.realtime.pool_half); GL rows bottom first.
#if defined POOL
uniform ivec2 u_src_size;
uniform ivec2 u_dst_size;
layout(IMG_FMT, binding = 1) writeonly uniform image2D u_dst;
void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    if (c.x >= u_dst_size.x || c.y >= u_dst_size.y) return;
    int j = u_dst_size.y - 1 - c.y;                     // the block's row, top first
    int y0 = min(2 * j, u_src_size.y - 1), y1 = min(2 * j + 1, u_src_size.y - 1);
    int x0 = min(2 * c.x, u_src_size.x - 1), x1 = min(2 * c.x + 1, u_src_size.x - 1);
    vec3 sum = texelFetch(u_t, ivec2(x0, u_src_size.y - 1 - y0), 0).rgb + texelFetch(u_t, ivec2(x1, u_src_size.y - 1 - y0), 0).rgb
             + texelFetch(u_t, ivec2(x0, u_src_size.y - 1 - y1), 0).rgb + texelFetch(u_t, ivec2(x1, u_src_size.y - 1 - y1), 0).rgb;
    imageStore(u_dst, c, vec4(stored3(0.25 * sum), 1.0));
}
#endif

// DELTA: the periphery's change at the level above its own (u_dst_size), bilinearly upsampled from
// its own level (u_src_size): from its guarded frame minus its target (u_out - u_t, FROM_FRAME) or
// from a change already upsampled once (u_delta).
#if defined DELTA
uniform ivec2 u_src_size;
uniform ivec2 u_dst_size;
#if defined FROM_FRAME
uniform sampler2D u_out;
vec3 change_at(ivec2 q) { return texelFetch(u_out, q, 0).rgb - texelFetch(u_t, q, 0).rgb; }
#else
uniform sampler2D u_delta;
vec3 change_at(ivec2 q) { return texelFetch(u_delta, q, 0).rgb; }
#endif
layout(rgba32f, binding = 1) writeonly uniform image2D u_dst;
#include "fovea_upsample.glsl"
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_dst_size.x || p.y >= u_dst_size.y) return;
#if defined SAME
    imageStore(u_dst, p, vec4(change_at(p), 1.0));       // the change at the level's own size
#else
    imageStore(u_dst, p, vec4(upsampled(p, u_dst_size, u_src_size), 1.0));
#endif
}
#endif

#if defined COMPOSE
uniform sampler2D u_q;          // the sub-image's state q (its grid; the sub-image at the origin)
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;
#if defined PERIPHERY
#include "fovea_periphery.glsl"
#endif
#include "fovea_window.glsl"

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_view.x || p.y >= u_view.y) return;
    imageStore(u_out, p, vec4(fovea_shown(p), 1.0));
}
#endif
#endif
