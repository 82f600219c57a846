// Separable low-rank 3x3 filter bank (vrcorrect.runtime.filters): a library for compute programs.
// Pass selection (define exactly one): PASS_DECODE, PASS_ROWS, PASS_COLS.
//   PASS_DECODE: u_source (RGBA8 code values or float) -> u_linear image (LINEAR_FMT, default
//                rgba32f; linear light).
//   PASS_ROWS:   u_linear -> u_rows_out (image2DArray, layer l holds components 4l..4l+3):
//                h_c(x, y) = sum_t row_c[t] * in_{channel(c)}(x - (t - R), y)
//   PASS_COLS:   u_rows_in (sampler2DArray) -> u_out (rgba32f): acc_i(x, Y) =
//                sum_l sum_t dot(col_{i,l}[t], h_l(x, Y - (t - R))), then combine(acc, target).
// All indices are GL texel coordinates (row 0 at the bottom; the caller flips the vertical taps).
// Defines: LAYERS (number of 4-component layers), RADIUS (R), BORDER_ZERO (else mirrored repeat),
// SOURCE_SRGB (PASS_DECODE: the source holds sRGB code values), LINEAR_HALF (PASS_DECODE: LINEAR_FMT
// is 16-bit), COMPARE (PASS_DECODE: set u_changed when any pixel differs from u_previous's).
#ifndef VRCORRECT_FILTER_BANK_GLSL
#define VRCORRECT_FILTER_BANK_GLSL

layout(local_size_x = 16, local_size_y = 16) in;

#include "borders.glsl"

#if defined PASS_DECODE
#ifndef LINEAR_FMT
#define LINEAR_FMT rgba32f
#endif
uniform sampler2D u_source;
layout(LINEAR_FMT, binding = 0) writeonly uniform image2D u_linear;
#if defined COMPARE
uniform sampler2D u_previous;                    // the last frame's decoded target
layout(std430, binding = 5) buffer Change { uint u_changed; };
shared uint group_changed;
#endif
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(u_linear);
    bool inside = p.x < size.x && p.y < size.y;
#if defined COMPARE
    if (gl_LocalInvocationIndex == 0u) group_changed = 0u;
    barrier();
#endif
    if (inside) {
        vec4 c = texelFetch(u_source, p, 0);
#if defined SOURCE_SRGB
        c.rgb = srgb_to_linear(c.rgb);
#endif
#if defined LINEAR_HALF
        // rounded to nearest before the store (a driver's own conversion may truncate: llvmpipe's does)
        c.rgb = vec3(unpackHalf2x16(packHalf2x16(c.rg)), unpackHalf2x16(packHalf2x16(vec2(c.b, 0.0))).x);
#endif
        imageStore(u_linear, p, vec4(c.rgb, 1.0));
#if defined COMPARE
        if (any(notEqual(c.rgb, texelFetch(u_previous, p, 0).rgb))) atomicOr(group_changed, 1u);
#endif
    }
#if defined COMPARE
    barrier();
    if (gl_LocalInvocationIndex == 0u && group_changed != 0u) atomicOr(u_changed, 1u);
#endif
}
#endif

#if defined PASS_ROWS
uniform sampler2D u_linear_in;          // rgba32f, linear light
uniform sampler2D u_row_taps;           // width 2R+1, height LAYERS: 4 components' taps per texel
uniform mat4x3 u_select[LAYERS];        // column c picks the input channel of component 4l+c
layout(rgba32f, binding = 1) writeonly uniform image2DArray u_rows_out;
void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID.xyz);
    ivec2 size = textureSize(u_linear_in, 0);
    if (p.x >= size.x || p.y >= size.y || p.z >= LAYERS) return;
    mat4x3 sel = u_select[p.z];
    vec4 acc = vec4(0.0);
    for (int t = 0; t <= 2 * RADIUS; ++t) {
        int x = p.x - (t - RADIUS);
#if defined BORDER_ZERO
        if (x < 0 || x >= size.x) continue;
#else
        x = mirror_index(x, size.x);
#endif
        vec3 rgb = texelFetch(u_linear_in, ivec2(x, p.y), 0).rgb;
        acc += texelFetch(u_row_taps, ivec2(t, p.z), 0) * (rgb * sel);
    }
    imageStore(u_rows_out, p, acc);
}
#endif

#if defined PASS_COLS
uniform sampler2D u_linear_in;          // the target, for combine()
uniform sampler2DArray u_rows_in;
uniform sampler2D u_col_taps;           // width 2R+1, height 3 * LAYERS: row i * LAYERS + l
layout(rgba32f, binding = 2) writeonly uniform image2D u_out;
vec3 combine(vec3 filtered, vec3 target);     // defined by the program including this file
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_linear_in, 0);
    if (p.x >= size.x || p.y >= size.y) return;
    vec3 acc = vec3(0.0);
    for (int l = 0; l < LAYERS; ++l) {
        for (int t = 0; t <= 2 * RADIUS; ++t) {
            int y = p.y - (t - RADIUS);
#if defined BORDER_ZERO
            if (y < 0 || y >= size.y) continue;
#else
            y = mirror_index(y, size.y);
#endif
            vec4 h = texelFetch(u_rows_in, ivec3(p.x, y, l), 0);
            acc.r += dot(texelFetch(u_col_taps, ivec2(t, l), 0), h);
            acc.g += dot(texelFetch(u_col_taps, ivec2(t, LAYERS + l), 0), h);
            acc.b += dot(texelFetch(u_col_taps, ivec2(t, 2 * LAYERS + l), 0), h);
        }
    }
    vec3 target = texelFetch(u_linear_in, p, 0).rgb;
    imageStore(u_out, p, vec4(combine(acc, target), 1.0));
}
#endif

#endif
