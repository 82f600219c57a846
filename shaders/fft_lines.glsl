#version 430 core
// The line transform of fft_line.glsl alone, on lines of a storage buffer (the tests hold it to
// numpy's FFT at every length and plan; a bench can time it): data holds GROUPS * LINES lines of LINE
// complex points one after another; one work group transforms LINES of them in place (unscaled).
// Defines: LINE, PER, WG (= LINE / PER), FFT_STAGES, FFT_RADICES (vrcorrect.runtime.fft.LinePlan),
// LINES, INVERSE, IN_LINE (the input reaches the transform through shared memory, as a row pass's
// inverse does), OUT_LINE (the output is left in shared memory, as a row pass's forward transform).
#if defined COMPUTE_SHADER
#if !defined LINES
#define LINES 1
#endif
layout(local_size_x = LINES, local_size_y = WG) in;
layout(std430, binding = 0) buffer Data { vec2 data[]; };
uniform sampler2D u_twiddle;                    // LINE x 1, rg32f: cos, sin of 2 pi k / LINE
shared vec2 line[LINE * LINES];
#define lid int(gl_LocalInvocationID.y)
#define LCOL int(gl_LocalInvocationID.x)
#define AT(i) ((i) * LINES + LCOL)
vec2 line_twiddle(int k) { return texelFetch(u_twiddle, ivec2(k, 0), 0).xy; }
#include "fft_line.glsl"

void main() {
    int base = (int(gl_WorkGroupID.x) * LINES + LCOL) * LINE;
#if defined INVERSE
    const float sign = 1.0;
#else
    const float sign = -1.0;
#endif
    vec2 own[PER];
#if defined IN_LINE
    barrier();
    for (int m = 0; m < PER; ++m) line[AT(lid + WG * m)] = data[base + lid + WG * m];
    barrier();
    fft_line(own, sign, true, false);
#elif defined OUT_LINE
    for (int m = 0; m < PER; ++m) own[m] = data[base + lid + WG * m];
    fft_line(own, sign, false, true);
    for (int m = 0; m < PER; ++m) own[m] = line[AT(lid + WG * m)];
#else
    for (int m = 0; m < PER; ++m) own[m] = data[base + lid + WG * m];
    fft_line(own, sign, false, false);
#endif
    for (int m = 0; m < PER; ++m) data[base + lid + WG * m] = own[m];
}
#endif
