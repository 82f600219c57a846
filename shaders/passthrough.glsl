#version 330 core
// Draws the texture u_source over the whole viewport (the fullscreen triangle).
// Defines (switches): DECODE_SRGB - treat samples as sRGB code values and output linear light;
// ENCODE_SRGB - encode the output to sRGB code values. Both: a round trip.
#include "fullscreen.glsl"
#include "srgb.glsl"

#if defined VERTEX_SHADER
out vec2 v_uv;

void main() {
    v_uv = fullscreen_uv(gl_VertexID);
    gl_Position = fullscreen_position(v_uv);
}
#endif

#if defined FRAGMENT_SHADER
uniform sampler2D u_source;
in vec2 v_uv;
out vec4 f_color;

void main() {
    vec4 c = texture(u_source, v_uv);
#if defined DECODE_SRGB
    c = srgb_to_linear(c);
#endif
#if defined ENCODE_SRGB
    c = linear_to_srgb(c);
#endif
    f_color = c;
}
#endif
