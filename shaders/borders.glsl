// Texel index helpers shared by the filtering programs. A library: #include "borders.glsl".
#ifndef VRCORRECT_BORDERS_GLSL
#define VRCORRECT_BORDERS_GLSL

// Mirrored repeat (edge texel repeated, period 2n): OpenGL's MIRRORED_REPEAT on texel indices,
// numpy's "symmetric" padding.
int mirror_index(int i, int n) {
    int m = i % (2 * n);
    if (m < 0) m += 2 * n;
    return m < n ? m : 2 * n - 1 - m;
}

#endif
