#version 330 core
// Draws (part of) the texture u_source into the current viewport, which the caller sets to a
// rectangle of the output (vrcorrect.runtime.gl.draw_fullscreen with rect=...): two eyes side by
// side in a mirror window, say. u_source_rect picks the part of the source, as (u0, v0, du, dv)
// in texture coordinates (vrcorrect.runtime.gl.uv_rect converts a top-left pixel rectangle);
// it defaults to the whole texture. Define ENCODE_SRGB to encode linear light to sRGB codes.
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
uniform vec4 u_source_rect = vec4(0.0, 0.0, 1.0, 1.0);
in vec2 v_uv;
out vec4 f_color;

void main() {
    vec4 c = texture(u_source, u_source_rect.xy + v_uv * u_source_rect.zw);
#if defined ENCODE_SRGB
    c = linear_to_srgb(c);
#endif
    f_color = c;
}
#endif
