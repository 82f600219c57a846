#version 430 core
// ADMM over frames, the real-time path's default (vrcorrect.runtime.strategies.admm; its CPU twin,
// equal per iteration to float tolerance, is vrcorrect.solvers.realtime.AdmmFrames, which states the
// mathematics). One frame, per eye:
//   ROWS_TARGET  decoded target t (image rows) -> its row spectra, 3 channels      [glasses target only]
//   COLUMNS      MODE_TARGET: column FFTs, T = K_ref t per frequency, inverse column FFTs
//   POOL         a cold frame's coarse level: the target's 2x2 block means (the last row or column
//                repeated where the size is odd), for the half-resolution ADMM that starts the frame
//   ROWS_START   T per grid row (inverse row FFTs; IDEAL: A t), stored inside the image; the warm
//                (or cold) start of the state w, q (a warm start reprojected by the motion outside
//                the edge band, a cold one upsampled from the coarse level where there is one);
//                the reflections a1, a2 -> row spectra, 6 channels
//   COLUMNS      MODE_ADMM: U = G (K^H A1 + n A2), KU = K U, G = (K^H K + n I)^-1 computed here
//   ROWS_UPDATE  u, Ku by inverse row FFTs; w += alpha (Ku - prox(w)), q += alpha (u - proj(q));
//                then the next a1, a2 (or, LAST, z = proj(q) and t for the guard) -> row spectra
//   COLUMNS      MODE_GUARD: K z and K t
//   ROWS_GUARD   r0 = K t - T, kd = K z - K t: each image row's sums <r0, kd>, <kd, kd>, <r0, r0>
//   GUARD_FINAL  the rows' sums -> beta = clip(-<r0, kd> / <kd, kd>, 0, 1) (the guard's weight)
//   PLAN         early stop: zero work groups for every pass above when the view is still and converged
//   BLEND        x = t + beta (proj(q) - t) into an image (previews; the frame's own present is
//                admm_present.glsl)
// The grid (NX x NY, each side 5-smooth: 2^a 3^b 5^c, vrcorrect.solvers.realtime.admm_grid) holds the
// image at the origin (GL texel coordinates, rows bottom first; the kernels' spectra are uploaded for
// the vertically flipped kernels) and a black surround. Row spectra are real-to-complex: each real
// channel keeps columns 0..NX/2 (HX = NX/2 + 1, NX odd or even) of its row transform, two channels
// transformed together as a + ib and split; u_spec is an HX x NY x 6 array of complex values, written
// in place by every pass. One work group per row (WG threads) or per LINES spectrum columns (WG
// threads each); each thread keeps PER values of each channel of its line in registers (WG * PER is
// the line's length), and a line is transformed by fft_line.glsl's mixed-radix Stockham FFT: radix
// 2, 3, 4, 5 and 8 butterflies in registers, one pass through shared memory between two stages, none
// at the ends of a column pass's transforms where the plan allows; twiddle factors are a table
// (u_twiddle: cos, sin of 2 pi k / LINE for k < LINE, the pass's own line) instead of cos/sin in
// every butterfly. PER, LINES and the plan are set for each pass on the CPU
// (vrcorrect.runtime.fft.line_plan; the strategy's work_groups, chosen by GPU time).
// HALF: 16-bit float storage (rg16f, rgba16f; arithmetic in 32 bits, and a value a pass both stores
// and uses is used as stored); else 32-bit.
// Defines: NX, NY, HX, IMG_W, IMG_H, HALF, IDEAL, one pass, its mode; a row or column pass also
// LINE (NX or NY), PER, WG = LINE / PER (the work group: a literal, as GLSL 4.30's layout asks),
// FFT_STAGES, FFT_RADICES and LINES (a column pass's lines a work group, default 1); LIGHT_CAP (a
// robust design: the box's upper end is min(1, 2 t + LIGHT_CAP) of the pixel's target t, not 1).
#if defined COMPUTE_SHADER

#if defined HALF
#define SPEC_FMT rg16f
#define IMG_FMT rgba16f
#else
#define SPEC_FMT rg32f
#define IMG_FMT rgba32f
#endif

// A value as a 16-bit texture holds it, rounded to nearest (packHalf2x16). Every value stored in a
// 16-bit texture goes through these first: a driver's own conversion in imageStore may truncate
// instead (Mesa's llvmpipe does), which would bias every stored value toward zero.
vec2 stored2(vec2 v) {
#if defined HALF
    return unpackHalf2x16(packHalf2x16(v));
#else
    return v;
#endif
}

vec3 stored(vec3 v) {
#if defined HALF
    return vec3(stored2(v.xy), stored2(vec2(v.z, 0.0)).x);
#else
    return v;
#endif
}

#include "light_cap.glsl"

vec2 cmul(vec2 a, vec2 b) { return vec2(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
vec2 conj2(vec2 a) { return vec2(a.x, -a.y); }
vec2 times_i(vec2 a) { return vec2(-a.y, a.x); }

#if defined ROWS_TARGET || defined ROWS_START || defined ROWS_UPDATE || defined ROWS_GUARD
#define ROWS_PASS
#endif

#if defined LINE
// LINES lines transformed together by one work group (a column pass's COLUMN_LINES; rows: 1): the
// threads of one line share gl_LocalInvocationID.x = LCOL, neighbouring threads hold neighbouring
// lines (their reads of one grid row sit side by side in memory), and the lines are interleaved in
// shared memory (point i of line LCOL at AT(i)).
#if !defined LINES
#define LINES 1
#endif
layout(local_size_x = LINES, local_size_y = WG) in;
shared vec2 line[LINE * LINES];
uniform sampler2D u_twiddle;                   // LINE x 1, rg32f: cos, sin of 2 pi k / LINE
layout(SPEC_FMT, binding = 0) uniform image2DArray u_spec;
#define lid int(gl_LocalInvocationID.y)
#define LCOL int(gl_LocalInvocationID.x)
#define AT(i) ((i) * LINES + LCOL)

vec2 line_twiddle(int k) { return texelFetch(u_twiddle, ivec2(k, 0), 0).xy; }
#include "fft_line.glsl"
#endif

#if defined ROWS_PASS
// Forward transform of the real pair (a, b) (PER values per thread at x = lid + WG m), split into
// the two half spectra, stored in layers la and lb of row `row` (lb < 0: b is zero, only a's kept).
void forward_pair(vec2 ab[PER], int row, int la, int lb) {
    fft_line(ab, -1.0, false, true);                 // the spectrum in line[], natural order
    for (int k = lid; k < HX; k += WG) {
        vec2 c = line[AT(k)];
        vec2 d = conj2(line[AT(k == 0 ? 0 : NX - k)]);
        imageStore(u_spec, ivec3(k, row, la), vec4(stored2(0.5 * (c + d)), 0.0, 0.0));
        if (lb >= 0) {
            vec2 e = 0.5 * (c - d);
            imageStore(u_spec, ivec3(k, row, lb), vec4(stored2(vec2(e.y, -e.x)), 0.0, 0.0));   // (c - d) / 2i
        }
    }
}

// Inverse transform of the half spectra in layers la, lb of row `row` (lb < 0: b is zero): the real
// pair (a, b) at x = lid + WG m, scaled by 1 / NX.
void inverse_pair(int row, int la, int lb, out vec2 ab[PER]) {
    barrier();                                       // line[] may still be read (fft_line.glsl)
    for (int k = lid; k < HX; k += WG) {
        vec2 A = imageLoad(u_spec, ivec3(k, row, la)).xy;
        vec2 B = lb >= 0 ? imageLoad(u_spec, ivec3(k, row, lb)).xy : vec2(0.0);
        bool self_mirrored = k == 0 || 2 * k == NX;  // a real row's DC and (NX even) Nyquist terms
        if (self_mirrored) { A.y = 0.0; B.y = 0.0; }
        line[AT(k)] = A + times_i(B);
        if (!self_mirrored) line[AT(NX - k)] = conj2(A) + times_i(conj2(B));
    }
    barrier();
    fft_line(ab, 1.0, true, false);
    for (int m = 0; m < PER; ++m) ab[m] *= 1.0 / float(NX);
}

// Three real pairs from six channels (two vec3 per position) and back: pair i is channels 2i and
// 2i + 1 (layers 2i, 2i + 1). One transform in a loop rather than three written out: the same work,
// a third of the code (the pair is chosen by branches, never by indexing, so nothing needs unrolling).
void forward_six(vec3 p[PER], vec3 q[PER], int row) {
    for (int pair = 0; pair < 3; ++pair) {
        vec2 ab[PER];
        for (int m = 0; m < PER; ++m)
            ab[m] = pair == 0 ? p[m].xy : pair == 1 ? vec2(p[m].z, q[m].x) : q[m].yz;
        forward_pair(ab, row, 2 * pair, 2 * pair + 1);
    }
}

void inverse_six(int row, out vec3 p[PER], out vec3 q[PER]) {
    for (int pair = 0; pair < 3; ++pair) {
        vec2 ab[PER];
        inverse_pair(row, 2 * pair, 2 * pair + 1, ab);
        for (int m = 0; m < PER; ++m) {
            if (pair == 0) p[m].xy = ab[m];
            else if (pair == 1) { p[m].z = ab[m].x; q[m].x = ab[m].y; }
            else q[m].yz = ab[m];
        }
    }
}

uniform float u_keep;          // the data step's keep = rho n / (2 + rho n)
uniform float u_alpha;         // over-relaxation

bool inside(ivec2 p) { return all(greaterThanEqual(p, ivec2(0))) && p.x < IMG_W && p.y < IMG_H; }
vec3 prox(vec3 w, vec3 T, bool in_image) { return in_image ? u_keep * w + (1.0 - u_keep) * T : w; }
vec3 proj(vec3 q, bool in_image, vec3 t) { return in_image ? clamp(q, vec3(0.0), box_top(t)) : vec3(0.0); }
// FOVEA (a foveated frame, vrcorrect.runtime.strategies.foveated): the image is the sub-image around
// the gaze; the data term holds on the window u_win (x0, y0, x1, y1: GL texels of the image, half
// open) only, and the rest of the image (the ring) is held to what the view shows there, u_hold (the
// target, or the periphery's correction): proj there is that value (the CPU twin:
// vrcorrect.solvers.foveated). proj_at's `held` is that value, `t` the target (the light cap's).
#if defined FOVEA
uniform ivec4 u_win;
uniform sampler2D u_hold;
vec3 held_at(ivec2 p, bool in_image) { return in_image ? texelFetch(u_hold, p, 0).rgb : vec3(0.0); }
bool in_data(ivec2 p) { return all(greaterThanEqual(p, u_win.xy)) && all(lessThan(p, u_win.zw)); }
#else
bool in_data(ivec2 p) { return inside(p); }
#endif
vec3 proj_at(vec3 q, ivec2 p, bool in_image, vec3 held, vec3 t) {
#if defined FOVEA
    if (in_image && !in_data(p)) return held;
#endif
    return proj(q, in_image, t);
}
#endif

// ------------------------------------------------------------------ ROWS_TARGET
#if defined ROWS_TARGET
uniform sampler2D u_t;                          // the decoded target, IMG_W x IMG_H
void main() {
    int y = int(gl_WorkGroupID.x);
    vec3 t[PER];
    for (int m = 0; m < PER; ++m) {
        int x = lid + WG * m;
        t[m] = x < IMG_W ? texelFetch(u_t, ivec2(x, y), 0).rgb : vec3(0.0);
    }
    vec2 ab[PER];
    for (int m = 0; m < PER; ++m) ab[m] = t[m].rg;
    forward_pair(ab, y, 0, 1);
    for (int m = 0; m < PER; ++m) ab[m] = vec2(t[m].b, 0.0);
    forward_pair(ab, y, 2, -1);
}
#endif

// ------------------------------------------------------------------ COLUMNS
#if defined COLUMNS
#if defined MODE_TARGET
#define CH_IN 3
#define CH_OUT 3
#define CH 3
#else
#define CH_IN 6
#define CH_OUT 6
#define CH 6
#endif
uniform sampler2DArray u_kernel;                // HX x NY x 9: K_ij (cone i, primary j) at layer 3 i + j
uniform int u_rows_in;                          // rows of u_spec holding data (the rest is zero)
uniform int u_rows_out;                         // rows of the result that are stored
uniform float u_norm2;                          // n = balance ||K||^2, the box split's weight

vec2 kernel_at(int kx, int ky, int i, int j) { return texelFetch(u_kernel, ivec3(kx, ky, 3 * i + j), 0).xy; }

// The channels' spectra in this thread's points (v[c][m]: channel c at ky = lid + WG m). The channel
// loops below transform one channel at a time and reach v through these, by branches rather than by
// indexing with the loop's counter: the loop then needs no unrolling (one transform's code, not six)
// and v stays in registers.
vec2 v[CH][PER];

void set_channel(int c, vec2 own[PER]) {
    for (int m = 0; m < PER; ++m) {
        if (c == 0) v[0][m] = own[m];
        else if (c == 1) v[1][m] = own[m];
#if CH > 3
        else if (c == 2) v[2][m] = own[m];
        else if (c == 3) v[3][m] = own[m];
        else if (c == 4) v[4][m] = own[m];
        else v[5][m] = own[m];
#else
        else v[2][m] = own[m];
#endif
    }
}

void get_channel(int c, out vec2 own[PER]) {
    for (int m = 0; m < PER; ++m) {
        if (c == 0) own[m] = v[0][m];
        else if (c == 1) own[m] = v[1][m];
#if CH > 3
        else if (c == 2) own[m] = v[2][m];
        else if (c == 3) own[m] = v[3][m];
        else if (c == 4) own[m] = v[4][m];
        else own[m] = v[5][m];
#else
        else own[m] = v[2][m];
#endif
    }
}

void main() {
    // this thread's spectrum column; a work group's last may lie past HX: it loads zeros, reads the
    // kernel's last column, stores nothing, and keeps to the barriers
    int kx = int(gl_WorkGroupID.x) * LINES + LCOL;
    bool column = kx < HX;
    int kx_read = min(kx, HX - 1);
    for (int c = 0; c < CH_IN; ++c) {
        vec2 own[PER];
        for (int m = 0; m < PER; ++m) {
            int ky = lid + WG * m;
            own[m] = column && ky < u_rows_in ? imageLoad(u_spec, ivec3(kx, ky, c)).xy : vec2(0.0);
        }
        fft_line(own, -1.0, false, false);
        set_channel(c, own);
    }
    for (int m = 0; m < PER; ++m) {
        int ky = lid + WG * m;
        vec2 K[3][3];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) K[i][j] = kernel_at(kx_read, ky, i, j);
#if defined MODE_TARGET
        vec2 x[3] = vec2[3](v[0][m], v[1][m], v[2][m]);
        for (int i = 0; i < 3; ++i) v[i][m] = cmul(K[i][0], x[0]) + cmul(K[i][1], x[1]) + cmul(K[i][2], x[2]);
#elif defined MODE_GUARD
        for (int half_ = 0; half_ < 2; ++half_) {
            int o = 3 * half_;
            vec2 x[3] = vec2[3](v[o][m], v[o + 1][m], v[o + 2][m]);
            for (int i = 0; i < 3; ++i)
                v[o + i][m] = cmul(K[i][0], x[0]) + cmul(K[i][1], x[1]) + cmul(K[i][2], x[2]);
        }
#else   // MODE_ADMM
        // R = K^H A1 + n A2
        vec2 R[3];
        for (int j = 0; j < 3; ++j)
            R[j] = cmul(conj2(K[0][j]), v[0][m]) + cmul(conj2(K[1][j]), v[1][m]) + cmul(conj2(K[2][j]), v[2][m])
                   + u_norm2 * v[3 + j][m];
        // G = (K^H K + n I)^-1 by cofactors (the matrix is Hermitian; its inverse too)
        vec2 M[3][3];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                M[i][j] = cmul(conj2(K[0][i]), K[0][j]) + cmul(conj2(K[1][i]), K[1][j]) + cmul(conj2(K[2][i]), K[2][j]);
        for (int i = 0; i < 3; ++i) M[i][i].x += u_norm2;
        vec2 A_ = cmul(M[1][1], M[2][2]) - cmul(M[1][2], M[2][1]);
        vec2 B_ = cmul(M[1][2], M[2][0]) - cmul(M[1][0], M[2][2]);
        vec2 C_ = cmul(M[1][0], M[2][1]) - cmul(M[1][1], M[2][0]);
        vec2 det = cmul(M[0][0], A_) + cmul(M[0][1], B_) + cmul(M[0][2], C_);
        vec2 inv_det = conj2(det) / dot(det, det);
        vec2 G[3][3];
        G[0][0] = cmul(A_, inv_det);
        G[0][1] = cmul(cmul(M[0][2], M[2][1]) - cmul(M[0][1], M[2][2]), inv_det);
        G[0][2] = cmul(cmul(M[0][1], M[1][2]) - cmul(M[0][2], M[1][1]), inv_det);
        G[1][0] = cmul(B_, inv_det);
        G[1][1] = cmul(cmul(M[0][0], M[2][2]) - cmul(M[0][2], M[2][0]), inv_det);
        G[1][2] = cmul(cmul(M[0][2], M[1][0]) - cmul(M[0][0], M[1][2]), inv_det);
        G[2][0] = cmul(C_, inv_det);
        G[2][1] = cmul(cmul(M[0][1], M[2][0]) - cmul(M[0][0], M[2][1]), inv_det);
        G[2][2] = cmul(cmul(M[0][0], M[1][1]) - cmul(M[0][1], M[1][0]), inv_det);
        vec2 U[3];
        for (int i = 0; i < 3; ++i) U[i] = cmul(G[i][0], R[0]) + cmul(G[i][1], R[1]) + cmul(G[i][2], R[2]);
        for (int i = 0; i < 3; ++i) {
            v[i][m] = U[i];
            v[3 + i][m] = cmul(K[i][0], U[0]) + cmul(K[i][1], U[1]) + cmul(K[i][2], U[2]);
        }
#endif
    }
    for (int c = 0; c < CH_OUT; ++c) {
        vec2 own[PER];
        get_channel(c, own);
        fft_line(own, 1.0, false, false);
        for (int m = 0; m < PER; ++m) {
            int ky = lid + WG * m;
            if (column && ky < u_rows_out)
                imageStore(u_spec, ivec3(kx, ky, c), vec4(stored2(own[m] * (1.0 / float(NY))), 0.0, 0.0));
        }
    }
}
#endif

// ------------------------------------------------------------------ POOL
// Coarse texel c (GL orientation, rows bottom first) holds the mean of fine texels 2c - o and
// 2c - o + 1 on each axis, clamped to the image, with o = 0 across and 2 ceil(H / 2) - H up: the
// blocks the CPU twin pools from the image's top-left corner (solvers.realtime.pool_half), seen
// from the bottom-left.
#if defined POOL
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_t;                          // the decoded target, IMG_W x IMG_H
layout(IMG_FMT, binding = 1) writeonly uniform image2D u_coarse_t;
void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    ivec2 n = (ivec2(IMG_W, IMG_H) + 1) / 2;
    if (any(greaterThanEqual(c, n))) return;
    ivec2 o = ivec2(0, 2 * n.y - IMG_H);
    ivec2 p0 = clamp(2 * c - o, ivec2(0), ivec2(IMG_W - 1, IMG_H - 1));
    ivec2 p1 = clamp(2 * c - o + 1, ivec2(0), ivec2(IMG_W - 1, IMG_H - 1));
    vec3 sum = texelFetch(u_t, p0, 0).rgb + texelFetch(u_t, ivec2(p1.x, p0.y), 0).rgb
             + texelFetch(u_t, ivec2(p0.x, p1.y), 0).rgb + texelFetch(u_t, p1, 0).rgb;
    imageStore(u_coarse_t, c, vec4(stored(0.25 * sum), 1.0));
}
#endif

// ------------------------------------------------------------------ ROWS_START
// The state is read from u_w_src, u_q_src and the last T from u_T_prev (a shifted warm start: other
// textures than those written, since a texel moved from elsewhere must not be read after it is
// written), or, u_in_place, from u_w, u_q, u_T themselves (an unshifted one: each texel read then
// written by one invocation). A shifted start leaves the edge band (u_band: the pixels next to the
// two edges across each axis the motion has) where it is: the edge's own correction belongs to the
// window. A cold start with u_coarse reads the coarse level's w, q from u_w_src, u_q_src and its T
// and t from u_T_prev, u_t_prev, and adds what the coarse iterations added to their start (w - T,
// q - t), upsampled (solvers.realtime.upsample_double, seen from the bottom-left), to its own.
#if defined ROWS_START
uniform sampler2D u_t;                          // this frame's target
uniform sampler2D u_t_prev;                     // the previous frame's target
uniform sampler2D u_T_prev;
uniform bool u_cold;
uniform bool u_in_place;
uniform bool u_start_given;                     // a cold start from u_start (a first guess) instead of t
uniform sampler2D u_start;
uniform ivec2 u_shift;                          // the content's motion since the last frame (GL texels)
uniform ivec2 u_band;                           // the edge band's width on each axis (0: none)
uniform bool u_coarse;                          // a cold start from the coarse level
uniform ivec2 u_coarse_size;                    // the coarse level's image, ceil(IMG_W / 2) x ceil(IMG_H / 2)
uniform mat3 u_matrix;                          // IDEAL: T = A t
layout(IMG_FMT, binding = 1) uniform image2D u_T;
layout(IMG_FMT, binding = 2) readonly uniform image2D u_w_src;
layout(IMG_FMT, binding = 3) readonly uniform image2D u_q_src;
layout(IMG_FMT, binding = 4) uniform image2D u_w;
layout(IMG_FMT, binding = 5) uniform image2D u_q;

bool in_band(ivec2 p) {
    return (u_band.x > 0 && (p.x < u_band.x || p.x >= IMG_W - u_band.x))
        || (u_band.y > 0 && (p.y < u_band.y || p.y >= IMG_H - u_band.y));
}

// One axis of the upsampling: the two coarse texels and the weight of the second.
void upsample_axis(int p, int o, int n, out int i0, out int i1, out float f) {
    float c = clamp((float(p) + 0.5 + float(o)) * 0.5 - 0.5, 0.0, float(n - 1));
    i0 = int(floor(c));
    i1 = min(i0 + 1, n - 1);
    f = c - float(i0);
}

// What the coarse iterations added to their cold start at coarse texel c: q - t, or w - T.
vec3 coarse_added(ivec2 c, bool of_q) {
    return of_q ? imageLoad(u_q_src, c).rgb - texelFetch(u_t_prev, c, 0).rgb
                : imageLoad(u_w_src, c).rgb - texelFetch(u_T_prev, c, 0).rgb;
}

vec3 upsampled(ivec2 p, bool of_q) {
    ivec2 o = ivec2(0, 2 * u_coarse_size.y - IMG_H);     // rows counted from the bottom (POOL)
    int x0, x1, y0, y1;
    float fx, fy;
    upsample_axis(p.x, o.x, u_coarse_size.x, x0, x1, fx);
    upsample_axis(p.y, o.y, u_coarse_size.y, y0, y1, fy);
    vec3 a = coarse_added(ivec2(x0, y0), of_q), b = coarse_added(ivec2(x0, y1), of_q);
    vec3 c = coarse_added(ivec2(x1, y0), of_q), d = coarse_added(ivec2(x1, y1), of_q);
    vec3 left = a * (1.0 - fy) + b * fy;                // rows first, as the twin
    vec3 right = c * (1.0 - fy) + d * fy;
    return left * (1.0 - fx) + right * fx;
}

void main() {
    int y = int(gl_WorkGroupID.x);
    vec3 T[PER];
#if defined IDEAL
    for (int m = 0; m < PER; ++m) {
        ivec2 p = ivec2(lid + WG * m, y);
        T[m] = inside(p) ? u_matrix * texelFetch(u_t, p, 0).rgb : vec3(0.0);
    }
#else
    {
        vec2 ab[PER], c0[PER];
        inverse_pair(y, 0, 1, ab);
        inverse_pair(y, 2, -1, c0);
        for (int m = 0; m < PER; ++m) T[m] = vec3(ab[m], c0[m].x);
    }
#endif
    vec3 a1[PER], a2[PER];
    for (int m = 0; m < PER; ++m) {
        ivec2 p = ivec2(lid + WG * m, y);
        bool in_image = inside(p);
        vec3 Tp = T[m];
        vec3 t = vec3(0.0);
        vec3 T_last = vec3(0.0);
        if (in_image) {
            Tp = stored(Tp);
            t = texelFetch(u_t, p, 0).rgb;
            if (u_in_place && !u_cold) T_last = imageLoad(u_T, p).rgb;
            imageStore(u_T, p, vec4(Tp, 1.0));
        }
        vec3 w, q;
        if (u_cold) {
            w = Tp;
            q = (u_start_given && in_image) ? clamp(texelFetch(u_start, p, 0).rgb, 0.0, 1.0) : t;
            if (u_coarse && in_image) {
                w += upsampled(p, false);
                q += upsampled(p, true);
            }
        } else if (u_in_place) {
            w = imageLoad(u_w, p).rgb;
            q = imageLoad(u_q, p).rgb;
            if (in_image) {
                w += Tp - T_last;
                q += t - texelFetch(u_t_prev, p, 0).rgb;
            }
        } else if (!in_image) {
            w = imageLoad(u_w_src, p).rgb;
            q = imageLoad(u_q_src, p).rgb;
        } else {
            ivec2 s = in_band(p) ? p : p - u_shift;
            if (inside(s)) {
                w = imageLoad(u_w_src, s).rgb + (Tp - texelFetch(u_T_prev, s, 0).rgb);
                q = imageLoad(u_q_src, s).rgb + (t - texelFetch(u_t_prev, s, 0).rgb);
            } else {                            // exposed by the motion: cold
                w = Tp;
                q = t;
            }
        }
        w = stored(w);
        q = stored(q);
        imageStore(u_w, p, vec4(w, 1.0));
        imageStore(u_q, p, vec4(q, 1.0));
        a1[m] = 2.0 * prox(w, Tp, in_data(p)) - w;
#if defined FOVEA
        a2[m] = 2.0 * proj_at(q, p, in_image, held_at(p, in_image), t) - q;
#else
        a2[m] = 2.0 * proj_at(q, p, in_image, t, t) - q;
#endif
    }
    forward_six(a1, a2, y);
}
#endif

// ------------------------------------------------------------------ ROWS_UPDATE
// (NO_UPDATE, with LAST: no iteration this frame; only the guard's input from the state as it is.)
#if defined ROWS_UPDATE
uniform sampler2D u_T;                          // this frame's T inside the image
uniform sampler2D u_t;                          // LAST or LIGHT_CAP: the target (the guard's, the cap's)
layout(IMG_FMT, binding = 2) uniform image2D u_w;
layout(IMG_FMT, binding = 3) uniform image2D u_q;
void main() {
    int y = int(gl_WorkGroupID.x);
#if !defined NO_UPDATE
    vec3 u[PER], Ku[PER];
    inverse_six(y, u, Ku);
#endif
    vec3 a1[PER], a2[PER];
    for (int m = 0; m < PER; ++m) {
        ivec2 p = ivec2(lid + WG * m, y);
        bool in_image = inside(p);
        vec3 q = imageLoad(u_q, p).rgb;
#if defined FOVEA
        vec3 tp = held_at(p, in_image);                 // the ring's value
#else
        vec3 tp = vec3(0.0);
#endif
#if defined LAST || defined LIGHT_CAP
        vec3 t = in_image ? texelFetch(u_t, p, 0).rgb : vec3(0.0);
#else
        vec3 t = vec3(0.0);                             // (box_top does not read it)
#endif
#if !defined NO_UPDATE
        vec3 T = in_image ? texelFetch(u_T, p, 0).rgb : vec3(0.0);
        vec3 w = imageLoad(u_w, p).rgb;
        vec3 pw = prox(w, T, in_data(p));
        vec3 pq = proj_at(q, p, in_image, tp, t);
        w = stored(w + u_alpha * (Ku[m] - pw));
        q = stored(q + u_alpha * (u[m] - pq));
        imageStore(u_w, p, vec4(w, 1.0));
        imageStore(u_q, p, vec4(q, 1.0));
#endif
#if defined LAST
        a1[m] = proj_at(q, p, in_image, tp, t);                        // z
        a2[m] = t;                                                     // t
#else
        a1[m] = 2.0 * prox(w, T, in_data(p)) - w;
        a2[m] = 2.0 * proj_at(q, p, in_image, tp, t) - q;
#endif
    }
#if defined LAST
    if (y >= IMG_H) return;                     // z and t are zero there (uniform per work group)
#endif
    forward_six(a1, a2, y);
}
#endif

// ------------------------------------------------------------------ ROWS_GUARD
#if defined ROWS_GUARD
uniform sampler2D u_T;
layout(std430, binding = 4) writeonly buffer Partials { vec4 u_partials[]; };

// The sum over the work group of every thread's `value`, in thread 0, through line[] (the line's
// shared memory: a work group of this pass has at most LINE threads, so no more is needed even at
// 4096 points, where line[] alone takes GL 4.3's 32 KiB).
vec2 group_sum(vec2 value) {
    barrier();
    line[lid] = value;
    barrier();
    int stride = 1;
    while (stride < WG) stride <<= 1;
    for (stride >>= 1; stride > 0; stride >>= 1) {
        if (lid < stride && lid + stride < WG) line[lid] += line[lid + stride];
        barrier();
    }
    return line[0];
}

void main() {
    int y = int(gl_WorkGroupID.x);
    vec3 Kz[PER], Kt[PER];
    inverse_six(y, Kz, Kt);
    vec4 s = vec4(0.0);
    for (int m = 0; m < PER; ++m) {
        ivec2 p = ivec2(lid + WG * m, y);
        if (p.x < IMG_W) {
            vec3 r0 = Kt[m] - texelFetch(u_T, p, 0).rgb;
            vec3 kd = Kz[m] - Kt[m];
            s += vec4(dot(r0, kd), dot(kd, kd), dot(r0, r0), 0.0);
        }
    }
    vec2 xy = group_sum(s.xy);
    float z = group_sum(vec2(s.z, 0.0)).x;
    if (lid == 0) u_partials[y] = vec4(xy, z, 0.0);
}
#endif

// ------------------------------------------------------------------ GUARD_FINAL
// The guard's weight as vrcorrect.solvers.guard_weight(<r0, Kd>, <Kd, Kd>, <r0, r0>) computes it on
// the CPU. Also keeps the guarded objective of this frame and the last (u_history, for PLAN),
// cleared by u_reset (a cold start).
#if defined GUARD_FINAL
layout(local_size_x = 256) in;
layout(std430, binding = 3) writeonly buffer Guard { float u_beta; float u_sums[3]; };
layout(std430, binding = 4) readonly buffer Partials { vec4 u_partials[]; };
layout(std430, binding = 6) buffer History { float u_history[2]; };
uniform bool u_reset;
shared vec4 sums[256];
#include "guard.glsl"
void main() {
    uint i = gl_LocalInvocationIndex;
    vec4 total = guard_sum_partials(i, IMG_H);
    if (i == 0u) {
        u_sums[0] = total.x;
        u_sums[1] = total.y;
        u_sums[2] = total.z;
        float beta = total.y > 1e-10 * total.z ? clamp(-total.x / total.y, 0.0, 1.0) : 0.0;
        u_beta = beta;
        u_history[1] = u_reset ? -1.0 : u_history[0];
        u_history[0] = total.z + 2.0 * beta * total.x + beta * beta * total.y;
    }
}
#endif

// ------------------------------------------------------------------ PLAN
// Early stop: this frame's passes run (their work groups, u_groups) unless the target is unchanged
// since the last frame (u_changed, set by the decode's comparison) and the last two frames'
// objectives agree to u_tolerance (converged); then every pass gets zero work groups (dispatched
// indirectly from u_args). Clears u_changed for the next frame.
#if defined PLAN
layout(local_size_x = 1) in;
layout(std430, binding = 5) buffer Change { uint u_changed; };
layout(std430, binding = 6) readonly buffer History { float u_history[2]; };
layout(std430, binding = 7) writeonly buffer Args { uint u_args[]; };
uniform int u_passes;
uniform int u_groups[MAX_PASSES];
uniform float u_tolerance;
void main() {
    float last = u_history[0], before = u_history[1];
    bool converged = before >= 0.0 && abs(last - before) <= u_tolerance * max(before, 1e-30);
    bool skip = u_changed == 0u && converged;
    for (int k = 0; k < u_passes; ++k) {
        u_args[3 * k] = skip ? 0u : uint(u_groups[k]);
        u_args[3 * k + 1] = 1u;
        u_args[3 * k + 2] = 1u;
    }
    u_changed = 0u;
}
#endif

// ------------------------------------------------------------------ BLEND
#if defined BLEND
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_t;
uniform sampler2D u_q;
layout(std430, binding = 3) readonly buffer Guard { float u_beta; float u_sums[3]; };
layout(rgba32f, binding = 1) writeonly uniform image2D u_out;
#if defined FOVEA
uniform ivec4 u_win;
uniform sampler2D u_hold;
#endif
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= IMG_W || p.y >= IMG_H) return;
    vec3 t = texelFetch(u_t, p, 0).rgb;
    vec3 z = clamp(texelFetch(u_q, p, 0).rgb, vec3(0.0), box_top(t));
#if defined FOVEA
    if (!(all(greaterThanEqual(p, u_win.xy)) && all(lessThan(p, u_win.zw)))) z = texelFetch(u_hold, p, 0).rgb;
#endif
    imageStore(u_out, p, vec4(t + u_beta * (z - t), 1.0));
}
#endif

#endif
