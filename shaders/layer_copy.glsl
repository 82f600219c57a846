#version 330 core
// The OpenXR layer's two passes around the Corrector (vrcorrect/runtime/layer/engine.py), each drawn with
// the fullscreen triangle over a viewport. Defines (switches):
//   DECODE  the application's submitted rect, texel for texel from u_source, into the layer's staging
//           texture (viewport: the rect's size at 0, 0): sRGB code values when u_stage_codes (an 8-bit
//           swapchain: what the Corrector takes and decodes itself), else linear light clamped to
//           [0, 1] (a 10-bit or float swapchain: a float texture the Corrector takes as linear light).
//   ENCODE  the Corrector's result (sRGB code values in u_result, the rect's size) into the target's
//           rect (viewport: the rect), in the swapchain's own encoding, with the source's alpha. For a
//           float swapchain (u_carry) the part of each source value outside [0, 1] is added back:
//           carried through uncorrected.
//   PACKED  source and target are raw 32-bit texels (a Vulkan image's memory imported as GL_R32UI),
//           unpacked and packed here as u_packing says; without it they are GL textures (an OpenGL
//           session's swapchain images, or a Vulkan half-float image imported as GL_RGBA16F) that GL
//           reads and writes in their own format (sRGB images decoded on read; an sRGB target is
//           written with its code values, GL_FRAMEBUFFER_SRGB off).
// A Vulkan image's first row is its top row, GL's is its bottom row: with u_flip the rect is read
// upside down into GL's orientation (which the Corrector works in) and written back the same way.
#include "fullscreen.glsl"
#include "srgb.glsl"

#if defined VERTEX_SHADER
void main() {
    gl_Position = fullscreen_position(fullscreen_uv(gl_VertexID));
}
#endif

#if defined FRAGMENT_SHADER
#define PACK_RGBA8 0
#define PACK_BGRA8 1
#define PACK_A2B10G10R10 2
#define ENCODING_SRGB 0       // the stored values are sRGB code values
#define ENCODING_LINEAR 1     // linear light, normalized (8- or 10-bit)
#define ENCODING_FLOAT 2      // linear light, any value

#if defined PACKED
uniform usampler2D u_source;
#else
uniform sampler2D u_source;
#endif
uniform int u_packing;        // PACKED: how the 32 bits hold the channels
uniform int u_encoding;
uniform ivec2 u_offset;       // the rect's first texel in the source (and the target)
uniform int u_height;         // the rect's height
uniform bool u_flip;

#if defined PACKED
vec4 unpack(uint v) {
    if (u_packing == PACK_A2B10G10R10)
        return vec4(float(v & 1023u), float((v >> 10) & 1023u), float((v >> 20) & 1023u), float(v >> 30)) /
               vec4(1023.0, 1023.0, 1023.0, 3.0);
    vec4 c = vec4(float(v & 255u), float((v >> 8) & 255u), float((v >> 16) & 255u), float(v >> 24)) / 255.0;
    return u_packing == PACK_BGRA8 ? c.bgra : c;
}

uint pack(vec4 c) {
    c = clamp(c, 0.0, 1.0);
    if (u_packing == PACK_A2B10G10R10) {
        uvec4 q = uvec4(round(c * vec4(1023.0, 1023.0, 1023.0, 3.0)));
        return q.r | (q.g << 10) | (q.b << 20) | (q.a << 30);
    }
    uvec4 q = uvec4(round((u_packing == PACK_BGRA8 ? c.bgra : c) * 255.0));
    return q.r | (q.g << 8) | (q.b << 16) | (q.a << 24);
}
#endif

// the source's linear light at texel p
vec4 source_linear(ivec2 p) {
#if defined PACKED
    vec4 c = unpack(texelFetch(u_source, p, 0).r);
    return u_encoding == ENCODING_SRGB ? srgb_to_linear(c) : c;
#else
    return texelFetch(u_source, p, 0);      // GL decodes an sRGB texture
#endif
}

// the texel of the source (and target) that staging texel q (GL orientation, rect-relative) stands for
ivec2 rect_texel(ivec2 q) {
    return u_offset + ivec2(q.x, u_flip ? u_height - 1 - q.y : q.y);
}

#if defined DECODE
uniform bool u_stage_codes;
out vec4 f_color;

void main() {
    vec4 c = source_linear(rect_texel(ivec2(gl_FragCoord.xy)));
    f_color = u_stage_codes ? linear_to_srgb(c) : clamp(c, 0.0, 1.0);
}
#endif

#if defined ENCODE
uniform sampler2D u_result;   // sRGB code values, GL orientation, the rect's size
uniform bool u_carry;
#if defined PACKED
out uvec4 f_packed;
#else
out vec4 f_color;
#endif

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    ivec2 q = t - u_offset;
    vec3 codes = texelFetch(u_result, ivec2(q.x, u_flip ? u_height - 1 - q.y : q.y), 0).rgb;
    vec4 source = source_linear(t);
    vec3 light = srgb_to_linear(codes);
    if (u_carry)
        light += source.rgb - clamp(source.rgb, 0.0, 1.0);
    vec4 value = vec4(u_encoding == ENCODING_SRGB ? codes : light, source.a);
#if defined PACKED
    f_packed = uvec4(pack(value), 0u, 0u, 0u);
#else
    f_color = value;
#endif
}
#endif
#endif
