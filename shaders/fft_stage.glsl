// One stage of fft_line.glsl's transform for one radix: included there once for each radix, with
// STAGE_R (the radix), STAGE_NAME (the function) and STAGE_DFT (its R-point DFT) defined.
// ns: the product of the radices before this stage. from_own: the input is own[] (the first stage,
// STAGE_R dividing PER), else line[]. to_own: leave the output in own[] (the last stage, STAGE_R
// dividing PER), else store it into line[] between two barriers.
#if !defined(STAGE_R) || !defined(STAGE_NAME) || !defined(STAGE_DFT)
#error fft_stage.glsl is a template: define STAGE_R, STAGE_NAME and STAGE_DFT before each include
#endif
void STAGE_NAME(int ns, float sign, bool from_own, bool to_own, inout vec2 own[PER]) {
    const int R = STAGE_R;
    const int B = (PER + R - 1) / R;                  // butterflies a thread
    const int J = LINE / R;                           // butterflies a line
    const int OWN_STEP = PER / R;                     // (from_own and to_own only: R divides PER)
    int span = ns * R;
    int step = LINE / span;                           // twiddle index of w: LINE / (ns R)
    precise vec2 v[B * R];
    for (int b = 0; b < B; ++b) {
        int j = lid + WG * b;
        if (j >= J) continue;                         // (only where R does not divide PER)
        precise vec2 x[R];
        for (int r = 0; r < R; ++r)
            x[r] = from_own ? own[b + r * OWN_STEP] : line[AT(j + r * J)];
        if (ns > 1) {
            int k = (j % ns) * step;
            for (int r = 1; r < R; ++r) {
                vec2 w = line_twiddle(r * k);
                x[r] = fft_cmul(x[r], vec2(w.x, sign * w.y));
            }
        }
        STAGE_DFT(x, sign);
        for (int r = 0; r < R; ++r) v[b * R + r] = x[r];
    }
    if (to_own) {                                     // (uniform: the same for every thread)
        for (int b = 0; b < B; ++b)
            for (int r = 0; r < R; ++r) own[b + r * OWN_STEP] = v[b * R + r];
    } else {
        barrier();
        for (int b = 0; b < B; ++b) {
            int j = lid + WG * b;
            if (j >= J) continue;
            int base = (j / ns) * span + j % ns;
            for (int r = 0; r < R; ++r) line[AT(base + r * ns)] = v[b * R + r];
        }
        barrier();
    }
}
