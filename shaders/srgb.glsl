// sRGB transfer function, IEC 61966-2-1: the exact piecewise curve of vrcorrect.display
// (decode: v / 12.92 up to 0.04045, else ((v + 0.055) / 1.055)^2.4; encode: 12.92 v up to
// 0.0031308, else 1.055 v^(1/2.4) - 0.055). Inputs are clamped to [0, 1] first; alpha is
// passed through. A library: #include "srgb.glsl" (guarded, so including it twice is fine).
#ifndef VRCORRECT_SRGB_GLSL
#define VRCORRECT_SRGB_GLSL

float srgb_to_linear(float v) {
    v = clamp(v, 0.0, 1.0);
    return v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4);
}

vec3 srgb_to_linear(vec3 v) {
    v = clamp(v, 0.0, 1.0);
    return mix(pow((v + 0.055) / 1.055, vec3(2.4)), v / 12.92, lessThanEqual(v, vec3(0.04045)));
}

vec4 srgb_to_linear(vec4 c) {
    return vec4(srgb_to_linear(c.rgb), c.a);
}

float linear_to_srgb(float v) {
    v = clamp(v, 0.0, 1.0);
    return v <= 0.0031308 ? v * 12.92 : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

vec3 linear_to_srgb(vec3 v) {
    v = clamp(v, 0.0, 1.0);
    return mix(1.055 * pow(v, vec3(1.0 / 2.4)) - 0.055, v * 12.92, lessThanEqual(v, vec3(0.0031308)));
}

vec4 linear_to_srgb(vec4 c) {
    return vec4(linear_to_srgb(c.rgb), c.a);
}

#endif
