#version 330 core
// The demo scene of `vrcorrect mirror` (vrcorrect.runtime.shell.scene.DemoScene): textured, lit
// geometry drawn once per eye into an RGBA8 target that holds sRGB code values.
// u_texture is an sRGB texture (GL_SRGB8_ALPHA8), so samples, filtering and mipmaps are in
// linear light; lighting and fog are computed in linear light and the result is encoded to
// sRGB code values on output (the Corrector decodes them again).
#include "srgb.glsl"

#if defined VERTEX_SHADER
uniform mat4 u_view_projection;
uniform mat4 u_model;
uniform vec2 u_uv_scale = vec2(1.0, 1.0);
uniform vec2 u_uv_offset = vec2(0.0, 0.0);
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_normal;
out vec3 v_world;
out vec2 v_uv;

void main() {
    vec4 world = u_model * vec4(in_position, 1.0);
    v_world = world.xyz;
    v_normal = mat3(u_model) * in_normal;     // rotations and uniform scales only
    v_uv = in_uv * u_uv_scale + u_uv_offset;
    gl_Position = u_view_projection * world;
}
#endif

#if defined FRAGMENT_SHADER
uniform sampler2D u_texture;
uniform vec3 u_light_direction;        // towards the light, world space, unit length
uniform float u_ambient = 0.35;        // share of light that does not depend on the normal
uniform float u_unlit = 0.0;           // 1: emissive surface (text banner), no shading
uniform vec3 u_camera;                 // eye position, world space (m)
uniform vec3 u_fog_colour;             // linear light
uniform float u_fog_per_m = 0.0;       // exponential fog density (1/m)
in vec3 v_normal;
in vec3 v_world;
in vec2 v_uv;
out vec4 f_color;

void main() {
    vec3 albedo = texture(u_texture, v_uv).rgb;
    float diffuse = max(dot(normalize(v_normal), u_light_direction), 0.0);
    float light = mix(u_ambient + (1.0 - u_ambient) * diffuse, 1.0, u_unlit);
    float fog = 1.0 - exp(-u_fog_per_m * distance(v_world, u_camera));
    vec3 c = mix(albedo * light, u_fog_colour, fog);
    f_color = vec4(linear_to_srgb(c), 1.0);
}
#endif
