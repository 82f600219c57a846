#version 430 core
// A foveated frame's two passes of its own (vrcorrect.runtime.strategies.foveated; the CPU twin is
// vrcorrect.solvers.foveated, which states the mathematics). GL texel coordinates, rows bottom first.
//   CROP     the sub-image (the window around the gaze and its ring) out of the view's decoded
//            target, into the ADMM strategy's target texture
//   COMPOSE  the view shown: the target outside the window; inside it the sub-image's guarded
//            solution t + beta (z - t), faded to the target over the blend band along the window's
//            edges that lie inside the view (a raised cosine, the twin's blend_ramp)
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
uniform ivec2 u_view;           // the view's size (W, H)
uniform ivec4 u_win;            // the window in the view: x0, x1 (columns) and y0, y1 (rows top first), half open
uniform float u_band;           // the blend band's width (0: no fade)
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;

// The weight along one axis at index i of a window [lo, hi) in a view of n: 1 in the middle,
// falling over the band to each edge that lies inside the view.
float ramp(float i, int lo, int hi, int n) {
    float r = 1.0;
    if (u_band > 0.0) {
        if (lo > 0) r = min(r, clamp((i - float(lo) + 0.5) / u_band, 0.0, 1.0));
        if (hi < n) r = min(r, clamp((float(hi) - 0.5 - i) / u_band, 0.0, 1.0));
    }
    return r;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_view.x || p.y >= u_view.y) return;
    vec3 t = texelFetch(u_t, p, 0).rgb;
    int row = u_view.y - 1 - p.y;                        // rows top first, as the window is given
    vec3 shown = t;
    if (p.x >= u_win.x && p.x < u_win.y && row >= u_win.z && row < u_win.w) {
        const float PI = 3.14159265358979;
        float rx = ramp(float(p.x), u_win.x, u_win.y, u_view.x);
        float ry = ramp(float(row), u_win.z, u_win.w, u_view.y);
        float a = (0.5 - 0.5 * cos(PI * rx)) * (0.5 - 0.5 * cos(PI * ry));
        vec3 z = clamp(texelFetch(u_q, p - u_origin, 0).rgb, 0.0, 1.0);
        vec3 s = t + u_beta * (z - t);
        shown = a >= 1.0 ? s : t + a * (s - t);
    }
    imageStore(u_out, p, vec4(shown, 1.0));
}
#endif
#endif
