#version 430 core
// A foveated frame's present (vrcorrect.runtime.strategies.foveated): the view composed as
// fovea_window.glsl states it, sRGB-encoded, drawn over the viewport in one pass (no float image of
// the view in between). u_t is the view's decoded target, u_q the sub-image's state, u_origin the
// sub-image's first texel in the view, beta the guard's weight (admm.glsl's GUARD_FINAL).
#include "fullscreen.glsl"
#include "srgb.glsl"

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
uniform ivec2 u_origin;
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
#if defined PERIPHERY
#include "fovea_periphery.glsl"
#endif
#include "fovea_window.glsl"
in vec2 v_uv;
out vec4 f_color;

void main() {
    ivec2 p = clamp(ivec2(v_uv * vec2(u_view)), ivec2(0), u_view - 1);
    f_color = vec4(linear_to_srgb(fovea_shown(p)), 1.0);
}
#endif
