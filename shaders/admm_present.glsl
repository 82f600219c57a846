#version 430 core
// The ADMM strategy's present (vrcorrect.runtime.strategies.admm): the guarded frame
// x = t + beta (clip(q, 0, 1) - t), sRGB-encoded, drawn over the viewport. t is the decoded target
// (u_size texels), q the state on the FFT grid (the image at its origin), beta the guard's weight
// (the storage buffer GUARD_FINAL wrote, admm.glsl). LIGHT_CAP (a robust design): q is clipped to
// min(1, 2 t + LIGHT_CAP) instead of 1, as admm.glsl's box.
#include "fullscreen.glsl"
#include "srgb.glsl"
#include "light_cap.glsl"

#if defined VERTEX_SHADER
out vec2 v_uv;

void main() {
    v_uv = fullscreen_uv(gl_VertexID);
    gl_Position = fullscreen_position(v_uv);
}
#endif

#if defined FRAGMENT_SHADER
uniform sampler2D u_t;
uniform sampler2D u_q;
uniform ivec2 u_size;
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
in vec2 v_uv;
out vec4 f_color;

void main() {
    ivec2 p = clamp(ivec2(v_uv * vec2(u_size)), ivec2(0), u_size - 1);
    vec3 t = texelFetch(u_t, p, 0).rgb;
    vec3 z = clamp(texelFetch(u_q, p, 0).rgb, vec3(0.0), box_top(t));
    f_color = vec4(linear_to_srgb(t + u_beta * (z - t)), 1.0);
}
#endif
