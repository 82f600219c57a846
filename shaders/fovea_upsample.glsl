// Bilinear upsampling by two (a library: #include after defining vec3 change_at(ivec2 q), the coarse
// level's value at its GL texel q): fine pixel y (rows top first) sits at coarse coordinate
// (y + 1/2) / 2 - 1/2, weights 3/4 and 1/4, clamped to the coarse level (edges repeated), as the CPU
// twin's vrcorrect.solvers.realtime.upsample_double; GL rows bottom first outside.
#ifndef FOVEA_UPSAMPLE_GLSL
#define FOVEA_UPSAMPLE_GLSL
vec3 upsampled(ivec2 p, ivec2 fine, ivec2 coarse) {
    vec2 at = (vec2(float(p.x), float(fine.y - 1 - p.y)) + 0.5) * 0.5 - 0.5;
    at = clamp(at, vec2(0.0), vec2(coarse - 1));
    ivec2 lo = ivec2(floor(at));
    ivec2 hi = min(lo + 1, coarse - 1);
    vec2 f = at - vec2(lo);
    vec3 a = change_at(ivec2(lo.x, coarse.y - 1 - lo.y)), b = change_at(ivec2(hi.x, coarse.y - 1 - lo.y));
    vec3 c = change_at(ivec2(lo.x, coarse.y - 1 - hi.y)), d = change_at(ivec2(hi.x, coarse.y - 1 - hi.y));
    return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
}
#endif
