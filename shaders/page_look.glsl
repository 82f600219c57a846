#version 430 core
// The real-time path's look at a frame for the page verdict (vrcorrect.runtime.strategies.base.PageLook):
// the relative luminance w . clamp(rgb, 0, 1) of every u_step-th pixel of every u_step-th row of the
// decoded linear frame (w: the display's luminance weights, white = 1), as
// vrcorrect.physics.page.page_verdict strides a picture, into u_look (u_out.x per row, GL's bottom row
// first); the CPU reads it two frames later and judges it (vrcorrect.physics.page.luminance_verdict).
#if defined COMPUTE_SHADER
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_linear;
uniform vec3 u_weights;
uniform ivec2 u_out;
uniform int u_step;
layout(std430, binding = 0) writeonly buffer Look { float u_look[]; };
void main() {
    ivec2 o = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(o, u_out))) return;
    vec3 rgb = clamp(texelFetch(u_linear, o * u_step, 0).rgb, vec3(0.0), vec3(1.0));
    u_look[o.y * u_out.x + o.x] = dot(rgb, u_weights);
}
#endif
