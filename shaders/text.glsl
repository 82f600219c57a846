#version 330 core
// Screen-space text and panels of `vrcorrect mirror` (vrcorrect.runtime.shell.mirror.TextOverlay):
// one instanced quad per glyph, drawn as a 4-vertex triangle strip with positions from
// gl_VertexID. Per instance: in_rect = (x, y, width, height) in target pixels with the
// origin at the target's top-left (image terms); in_uv = (u_left, v_top, u_right, v_bottom)
// in the font atlas (GL texture coordinates); in_colour = RGBA, alpha scales the glyph's
// coverage (the atlas' red channel). Blend with SRC_ALPHA, ONE_MINUS_SRC_ALPHA.

#if defined VERTEX_SHADER
uniform vec2 u_target_size;            // pixels of the viewport drawn into
in vec4 in_rect;
in vec4 in_uv;
in vec4 in_colour;
out vec2 v_uv;
out vec4 v_colour;

void main() {
    // strip order: (0, 0), (1, 0), (0, 1), (1, 1); corner.y = 0 is the quad's top
    vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1));
    vec2 pixel = in_rect.xy + corner * in_rect.zw;
    gl_Position = vec4(2.0 * pixel.x / u_target_size.x - 1.0, 1.0 - 2.0 * pixel.y / u_target_size.y, 0.0, 1.0);
    v_uv = vec2(mix(in_uv.x, in_uv.z, corner.x), mix(in_uv.y, in_uv.w, corner.y));
    v_colour = in_colour;
}
#endif

#if defined FRAGMENT_SHADER
uniform sampler2D u_atlas;
in vec2 v_uv;
in vec4 v_colour;
out vec4 f_color;

void main() {
    f_color = vec4(v_colour.rgb, v_colour.a * texture(u_atlas, v_uv).r);
}
#endif
