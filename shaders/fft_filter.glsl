#version 430 core
// A 3x3 filter bank applied by FFT (compute shaders): cost per pixel O(log N), whatever the
// filter's size, and no truncation. The image (W x H, linear light) sits on a periodic
// Nx x Ny grid (each side 5-smooth: 2^a 3^b 5^c) at offset (MARGIN, NY - H - MARGIN); the rest of the
// grid is filled by mirrored repeat of the image (BORDER_ZERO: black). Rows are GL's (bottom first):
// GL grid row r is row NY - 1 - r of the CPU's grid, which holds the image at (margin, margin), so
// the two grids are each other's vertical flip exactly, whatever the grid's surplus beyond
// H + 2 MARGIN (the bank's spectrum is uploaded flipped: F(fx, -fy)). Channels are packed two per complex
// signal: layer 0 = R + iG, layer 1 = B. Passes (define exactly one):
//   ROWS_FORWARD  load rows (grid fill) and FFT them           -> u_spec (rg32f array, 2 layers)
//   COLS          FFT columns of u_spec in place (sign by INVERSE)
//   MULTIPLY      unpack X_R, X_G, X_B; Y_i = sum_j F_ij X_j (ADJOINT: conj(F_ji)); pack -> u_spec_out
//   ROWS_INVERSE  inverse FFT of rows, keep the image's window  -> u_filtered (rg32f array)
//   COMBINE       u_filtered + target -> u_out (rgba32f): correction blend, delta, clip, raw,
//                 residual (v - u_other) or a FISTA update of u_x, u_y
// A line is transformed by fft_line.glsl's mixed-radix Stockham FFT (one work group a line, WG
// threads of PER points each; twiddle factors computed, not read: this bank binds no table).
// Defines: NX, NY, MARGIN, BORDER_ZERO, ADJOINT, the COMBINE mode; a row or column pass also LINE,
// PER, WG and FFT_SEQUENCE (vrcorrect.runtime.fft.LinePlan.defines).
// With BORDER_ZERO the fill, the product and the crop are an exact linear convolution with black
// outside the image, and the ADJOINT product is its exact adjoint (correlation, then the crop).
#include "srgb.glsl"

#if defined COMPUTE_SHADER
#define PI 3.14159265358979323846

#if defined ROWS_FORWARD || defined COLS || defined ROWS_INVERSE
#define LINES 1
layout(local_size_x = WG) in;
shared vec2 line[LINE];
#define lid int(gl_LocalInvocationID.x)
#define AT(i) (i)
vec2 line_twiddle(int k) {
    float a = 2.0 * PI * float(k) / float(LINE);
    return vec2(cos(a), sin(a));
}
#include "fft_line.glsl"
#else
layout(local_size_x = 16, local_size_y = 16) in;
#endif

#include "borders.glsl"

#if defined ROWS_FORWARD
uniform sampler2D u_linear_in;
layout(rg32f, binding = 0) writeonly uniform image2DArray u_spec;
void main() {
    int row = int(gl_WorkGroupID.x);
    int layer = int(gl_WorkGroupID.y);
    ivec2 size = textureSize(u_linear_in, 0);
    int y = row - (NY - size.y - MARGIN);
#if defined BORDER_ZERO
    bool row_inside = y >= 0 && y < size.y;
#else
    y = mirror_index(y, size.y);
    bool row_inside = true;
#endif
    vec2 own[PER];
    for (int m = 0; m < PER; ++m) {
        int x = lid + WG * m - MARGIN;
        vec2 value = vec2(0.0);
#if defined BORDER_ZERO
        bool inside = row_inside && x >= 0 && x < size.x;
#else
        x = mirror_index(x, size.x);
        bool inside = true;
#endif
        if (inside) {
            vec3 rgb = texelFetch(u_linear_in, ivec2(x, y), 0).rgb;
            value = layer == 0 ? rgb.rg : vec2(rgb.b, 0.0);
        }
        own[m] = value;
    }
    fft_line(own, -1.0, false, false);
    for (int m = 0; m < PER; ++m)
        imageStore(u_spec, ivec3(lid + WG * m, row, layer), vec4(own[m], 0.0, 0.0));
}
#endif

#if defined COLS
layout(rg32f, binding = 0) uniform image2DArray u_spec;
void main() {
    int col = int(gl_WorkGroupID.x);
    int layer = int(gl_WorkGroupID.y);
    vec2 own[PER];
    for (int m = 0; m < PER; ++m) own[m] = imageLoad(u_spec, ivec3(col, lid + WG * m, layer)).xy;
#if defined INVERSE
    fft_line(own, 1.0, false, false);
#else
    fft_line(own, -1.0, false, false);
#endif
    for (int m = 0; m < PER; ++m) imageStore(u_spec, ivec3(col, lid + WG * m, layer), vec4(own[m], 0.0, 0.0));
}
#endif

#if defined MULTIPLY
layout(rg32f, binding = 0) readonly uniform image2DArray u_spec;
layout(rg32f, binding = 1) writeonly uniform image2DArray u_spec_out;
uniform sampler2DArray u_bank;      // layer 3 i + j: F_ij at (fx, fy), complex in .xy
vec2 cmul(vec2 a, vec2 b) { return vec2(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
vec2 conj2(vec2 a) { return vec2(a.x, -a.y); }
void main() {
    ivec2 f = ivec2(gl_GlobalInvocationID.xy);
    if (f.x >= NX || f.y >= NY) return;
    ivec2 g = ivec2((NX - f.x) % NX, (NY - f.y) % NY);            // -f
    vec2 z = imageLoad(u_spec, ivec3(f, 0)).xy;
    vec2 zn = conj2(imageLoad(u_spec, ivec3(g, 0)).xy);
    vec2 x[3];
    x[0] = 0.5 * (z + zn);                                         // R
    vec2 d = 0.5 * (z - zn);
    x[1] = vec2(d.y, -d.x);                                        // G = (z - conj z(-f)) / 2i
    x[2] = imageLoad(u_spec, ivec3(f, 1)).xy;                      // B
    vec2 y[3];
    for (int i = 0; i < 3; ++i) {
        y[i] = vec2(0.0);
        for (int j = 0; j < 3; ++j)
#if defined ADJOINT
            y[i] += cmul(conj2(texelFetch(u_bank, ivec3(f, 3 * j + i), 0).xy), x[j]);
#else
            y[i] += cmul(texelFetch(u_bank, ivec3(f, 3 * i + j), 0).xy, x[j]);
#endif
    }
    imageStore(u_spec_out, ivec3(f, 0), vec4(y[0] + vec2(-y[1].y, y[1].x), 0.0, 0.0));   // Y_R + i Y_G
    imageStore(u_spec_out, ivec3(f, 1), vec4(y[2], 0.0, 0.0));
}
#endif

#if defined ROWS_INVERSE
layout(rg32f, binding = 0) readonly uniform image2DArray u_spec;
layout(rg32f, binding = 1) writeonly uniform image2DArray u_filtered;   // W x H x 2
uniform ivec2 u_size;
void main() {
    int row = int(gl_WorkGroupID.x);
    int layer = int(gl_WorkGroupID.y);
    int y = row - (NY - u_size.y - MARGIN);
    if (y < 0 || y >= u_size.y) return;                            // uniform per workgroup
    vec2 own[PER];
    for (int m = 0; m < PER; ++m) own[m] = imageLoad(u_spec, ivec3(lid + WG * m, row, layer)).xy;
    fft_line(own, 1.0, false, false);
    float scale = 1.0 / (float(NX) * float(NY));
    for (int m = 0; m < PER; ++m) {
        int x = lid + WG * m - MARGIN;
        if (x >= 0 && x < u_size.x) imageStore(u_filtered, ivec3(x, y, layer), vec4(own[m] * scale, 0.0, 0.0));
    }
}
#endif

#if defined COMBINE
// COMBINE_CORRECT: t + beta (clip(v) - t) with beta = u_beta; COMBINE_DELTA: clip(v) - t (the
// per-frame blend, blend.glsl, takes it from there); COMBINE_CLIP: clip(v); COMBINE_RESIDUAL:
// v - u_other (K y - T); COMBINE_FISTA: v is the gradient K^H (K y - T) at u_y: one projected-
// gradient step x' = clip(y - u_step v, 0, 1), then y' = x' + u_weight (x' - x), both in place
// (vrcorrect.solvers.fista.projected_gradient); else v as it is.
layout(rg32f, binding = 0) readonly uniform image2DArray u_filtered;
uniform sampler2D u_linear_in;
#if defined COMBINE_FISTA
layout(rgba32f, binding = 1) uniform image2D u_y;
layout(rgba32f, binding = 2) uniform image2D u_x;
uniform float u_step;
uniform float u_weight;
#else
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;
uniform float u_beta;
uniform sampler2D u_other;
#endif
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_linear_in, 0);
    if (p.x >= size.x || p.y >= size.y) return;
    vec2 rg = imageLoad(u_filtered, ivec3(p, 0)).xy;
    float b = imageLoad(u_filtered, ivec3(p, 1)).x;
    vec3 v = vec3(rg, b);
#if defined COMBINE_FISTA
    vec3 x = imageLoad(u_x, p).rgb;
    vec3 x_new = clamp(imageLoad(u_y, p).rgb - u_step * v, 0.0, 1.0);
    imageStore(u_x, p, vec4(x_new, 1.0));
    imageStore(u_y, p, vec4(x_new + u_weight * (x_new - x), 1.0));
#else
#if defined COMBINE_CORRECT
    vec3 t = texelFetch(u_linear_in, p, 0).rgb;
    vec3 outc = t + u_beta * (clamp(v, 0.0, 1.0) - t);
#elif defined COMBINE_DELTA
    vec3 outc = clamp(v, 0.0, 1.0) - texelFetch(u_linear_in, p, 0).rgb;
#elif defined COMBINE_CLIP
    vec3 outc = clamp(v, 0.0, 1.0);
#elif defined COMBINE_RESIDUAL
    vec3 outc = v - texelFetch(u_other, p, 0).rgb;
#else
    vec3 outc = v;
#endif
    imageStore(u_out, p, vec4(outc, 1.0));
#endif
}
#endif
#endif
