// One line of LINE complex points transformed by one work group's threads: a Stockham (self-sorting)
// mixed-radix FFT, the plan chosen on the CPU (vrcorrect.runtime.fft.line_plan). Each of WG threads
// a line owns PER points (WG * PER == LINE; thread i the points i + WG m, m < PER), and each stage of
// radix R does ceil(PER / R) radix-R butterflies a thread in registers; between two stages the points
// cross through shared memory once. A first stage whose radix divides PER reads the thread's own
// points straight from its registers, and a last one whose radix divides PER leaves them there, so a
// transform from and to registers (the column passes') crosses shared memory one time less a stage
// than it has stages.
//
// Stage s (radix R, ns the product of the radices before it) takes butterfly j < LINE / R from the
// points j + r LINE / R, multiplies point r by w^(r (j mod ns)) with w = exp(sign 2 pi i / (ns R)),
// transforms the R points, and stores output r at (j / ns) ns R + (j mod ns) + r ns: after the last
// stage the line is in natural order (no bit reversal).
//
// The includer defines: LINE, PER, WG, FFT_SEQUENCE (the stages' calls, from the plan), LINES
// (lines a work group) and AT(i) (where point i of this thread's line sits in shared memory), `lid`
// (this thread's index in its line), the shared array `line[]` (at least LINE * LINES vec2) and
// `vec2 line_twiddle(int k)`: exp(2 pi i k / LINE) for 0 <= k < LINE (from a table).
//
// Barriers: every store into line[] is preceded and followed by barrier() (so a transform may follow
// any reads of line[] and be followed by any), and a caller that fills line[] itself does the same.
// Every thread of the work group must call these functions (uniform control flow).
#ifndef FFT_LINE_GLSL
#define FFT_LINE_GLSL

vec2 fft_cmul(vec2 a, vec2 b) { return vec2(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
// sign * i * a
vec2 fft_rot(vec2 a, float sign) { return sign * vec2(-a.y, a.x); }

// The R-point DFTs, X_q = sum_r x_r exp(sign 2 pi i r q / R), in place.
void fft_dft2(inout vec2 x[2], float sign) {
    vec2 a = x[0];
    x[0] = a + x[1];
    x[1] = a - x[1];
}

void fft_dft3(inout vec2 x[3], float sign) {
    const float H = 0.86602540378443865;             // sin(2 pi / 3)
    vec2 s = x[1] + x[2];
    vec2 d = fft_rot(x[1] - x[2], sign) * H;
    vec2 m = x[0] - 0.5 * s;
    x[0] = x[0] + s;
    x[1] = m + d;
    x[2] = m - d;
}

void fft_dft4(inout vec2 x[4], float sign) {
    vec2 t0 = x[0] + x[2], t1 = x[0] - x[2];
    vec2 t2 = x[1] + x[3], t3 = fft_rot(x[1] - x[3], sign);
    x[0] = t0 + t2;
    x[1] = t1 + t3;
    x[2] = t0 - t2;
    x[3] = t1 - t3;
}

void fft_dft5(inout vec2 x[5], float sign) {
    const float C1 = 0.30901699437494742, C2 = -0.80901699437494742;   // cos(2 pi / 5), cos(4 pi / 5)
    const float S1 = 0.95105651629515357, S2 = 0.58778525229247313;    // sin(2 pi / 5), sin(4 pi / 5)
    vec2 s1 = x[1] + x[4], d1 = x[1] - x[4];
    vec2 s2 = x[2] + x[3], d2 = x[2] - x[3];
    vec2 a = x[0] + C1 * s1 + C2 * s2;
    vec2 b = fft_rot(S1 * d1 + S2 * d2, sign);
    vec2 c = x[0] + C2 * s1 + C1 * s2;
    vec2 d = fft_rot(S2 * d1 - S1 * d2, sign);
    x[0] = x[0] + s1 + s2;
    x[1] = a + b;
    x[4] = a - b;
    x[2] = c + d;
    x[3] = c - d;
}

void fft_dft8(inout vec2 x[8], float sign) {
    const float R2 = 0.70710678118654752;             // 1 / sqrt(2)
    vec2 e[4] = vec2[4](x[0], x[2], x[4], x[6]);
    vec2 o[4] = vec2[4](x[1], x[3], x[5], x[7]);
    fft_dft4(e, sign);
    fft_dft4(o, sign);
    o[1] = (o[1] + fft_rot(o[1], sign)) * R2;          // times exp(sign 2 pi i / 8)
    o[2] = fft_rot(o[2], sign);                        // times sign i
    o[3] = (fft_rot(o[3], sign) - o[3]) * R2;          // times exp(sign 6 pi i / 8)
    for (int q = 0; q < 4; ++q) {
        x[q] = e[q] + o[q];
        x[q + 4] = e[q] - o[q];
    }
}

// The stages, one function a radix (fft_stage.glsl, included once for each).
#define STAGE_R 2
#define STAGE_NAME fft_stage2
#define STAGE_DFT fft_dft2
#include "fft_stage.glsl"
#undef STAGE_R
#undef STAGE_NAME
#undef STAGE_DFT
#define STAGE_R 3
#define STAGE_NAME fft_stage3
#define STAGE_DFT fft_dft3
#include "fft_stage.glsl"
#undef STAGE_R
#undef STAGE_NAME
#undef STAGE_DFT
#define STAGE_R 4
#define STAGE_NAME fft_stage4
#define STAGE_DFT fft_dft4
#include "fft_stage.glsl"
#undef STAGE_R
#undef STAGE_NAME
#undef STAGE_DFT
#define STAGE_R 5
#define STAGE_NAME fft_stage5
#define STAGE_DFT fft_dft5
#include "fft_stage.glsl"
#undef STAGE_R
#undef STAGE_NAME
#undef STAGE_DFT
#define STAGE_R 8
#define STAGE_NAME fft_stage8
#define STAGE_DFT fft_dft8
#include "fft_stage.glsl"
#undef STAGE_R
#undef STAGE_NAME
#undef STAGE_DFT

// Before a first stage whose radix does not divide PER: the input into line[] (unless it is there).
void fft_to_line(inout vec2 own[PER], bool in_line) {
    if (!in_line) {
        barrier();
        for (int m = 0; m < PER; ++m) line[AT(lid + WG * m)] = own[m];
        barrier();
    }
}

// After a last stage whose radix does not divide PER: the output from line[] (unless it stays there).
void fft_from_line(inout vec2 own[PER], bool out_line) {
    if (!out_line)
        for (int m = 0; m < PER; ++m) own[m] = line[AT(lid + WG * m)];
}

// The unscaled transform of this thread's line (sign -1: forward, +1: inverse). in_line: the input is
// in line[] in natural order (the caller stored it, between barriers), else in own[] (own[m] is point
// lid + WG m). out_line: leave the output in line[] in natural order (readable by any thread: a
// barrier follows), else in own[]. FFT_SEQUENCE is the plan written out by the CPU
// (vrcorrect.runtime.fft.LinePlan.defines): one call a stage, each with its radix and ns as literals,
// the first stage reading own[] (from_own = !in_line) where its radix divides PER, the last leaving
// the output in own[] (to_own = !out_line) where its radix does, and fft_to_line / fft_from_line
// where they do not.
void fft_line(inout vec2 own[PER], float sign, bool in_line, bool out_line) {
    FFT_SEQUENCE
}

#endif
