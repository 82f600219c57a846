// A foveated frame's view at one texel (a library: #include "fovea_window.glsl" in a stage that
// declares u_t, u_q, u_origin and the Guard buffer, and with PERIPHERY includes fovea_periphery.glsl
// first): the target (or the periphery's correction) outside the window; inside it the
// sub-image's guarded solution t + beta (clip(q, 0, box_top(t)) - t), faded to the target over the blend band
// along the window's edges that lie inside the view, a raised cosine on each axis (the CPU twin's
// vrcorrect.solvers.foveated.blend_ramp).
#ifndef FOVEA_WINDOW_GLSL
#define FOVEA_WINDOW_GLSL
#include "light_cap.glsl"
uniform ivec2 u_view;           // the view's size (W, H)
uniform ivec4 u_win;            // the window in the view: x0, x1 (columns) and y0, y1 (rows top first), half open
uniform float u_band;           // the blend band's width (0: no fade)

float fovea_ramp(float i, int lo, int hi, int n) {
    float r = 1.0;
    if (u_band > 0.0) {
        if (lo > 0) r = min(r, clamp((i - float(lo) + 0.5) / u_band, 0.0, 1.0));
        if (hi < n) r = min(r, clamp((float(hi) - 0.5 - i) / u_band, 0.0, 1.0));
    }
    return 0.5 - 0.5 * cos(3.14159265358979 * r);
}

vec3 fovea_shown(ivec2 p) {
    vec3 t = texelFetch(u_t, p, 0).rgb;
#if defined PERIPHERY
    vec3 base = periphery_shown(p, t);                  // what the view shows outside the window
#else
    vec3 base = t;
#endif
    int row = u_view.y - 1 - p.y;                        // rows top first, as the window is given
    if (p.x < u_win.x || p.x >= u_win.y || row < u_win.z || row >= u_win.w) return base;
    float a = fovea_ramp(float(p.x), u_win.x, u_win.y, u_view.x) * fovea_ramp(float(row), u_win.z, u_win.w, u_view.y);
    vec3 z = clamp(texelFetch(u_q, p - u_origin, 0).rgb, vec3(0.0), box_top(t));
    vec3 s = t + u_beta * (z - t);
    return a >= 1.0 ? s : base + a * (s - base);
}
#endif
