#version 430 core
// The start of a frame's projected-gradient (FISTA) iterations, per pixel (vrcorrect.runtime.corrector,
// filter "fista"). The iterations themselves are fft_filter.glsl's RESIDUAL and FISTA combines.
//   cold (u_cold): x = y = t, the target (the first frame of a size, after a prescription change
//                  or a reset);
//   warm: the previous frame's solution moved by the content's motion u_shift (whole texels, GL
//         coordinates: t(p) ~ t_prev(p - u_shift)) and by the change of target that is left,
//         with q = p - u_shift:
//           x = clip(x_prev(q) + t(p) - t_prev(q)),  y = y_prev(q) + t(p) - t_prev(q)
//         where q lies inside the image, else x = y = t(p) (pixels the motion exposes). With
//         u_shift = (0, 0) this is x = clip(x + t - t_prev), y = y + t - t_prev: a still source
//         leaves both as they were (FISTA goes on where it stopped, momentum included);
// and t_prev = t for the next frame. Bindings: u_x 0, u_y 1, u_t_prev 2 (rgba32f, written; read too
// when u_shift = 0); with a shift the previous state is read from u_x_src 3, u_y_src 4,
// u_t_prev_src 5 (other textures: a texel moved from elsewhere must not be read after it is written).
#if defined COMPUTE_SHADER
layout(local_size_x = 16, local_size_y = 16) in;
uniform sampler2D u_linear_in;                       // this frame's target t (linear light)
uniform bool u_cold;
uniform ivec2 u_shift;
layout(rgba32f, binding = 0) uniform image2D u_x;
layout(rgba32f, binding = 1) uniform image2D u_y;
layout(rgba32f, binding = 2) uniform image2D u_t_prev;
layout(rgba32f, binding = 3) uniform readonly image2D u_x_src;
layout(rgba32f, binding = 4) uniform readonly image2D u_y_src;
layout(rgba32f, binding = 5) uniform readonly image2D u_t_prev_src;
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_linear_in, 0);
    if (p.x >= size.x || p.y >= size.y) return;
    vec3 t = texelFetch(u_linear_in, p, 0).rgb;
    vec3 x = t;
    vec3 y = t;
    if (!u_cold) {
        if (u_shift == ivec2(0)) {
            vec3 change = t - imageLoad(u_t_prev, p).rgb;
            x = clamp(imageLoad(u_x, p).rgb + change, 0.0, 1.0);
            y = imageLoad(u_y, p).rgb + change;
        } else {
            ivec2 q = p - u_shift;
            if (all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size))) {
                vec3 change = t - imageLoad(u_t_prev_src, q).rgb;
                x = clamp(imageLoad(u_x_src, q).rgb + change, 0.0, 1.0);
                y = imageLoad(u_y_src, q).rgb + change;
            }
        }
    }
    imageStore(u_x, p, vec4(x, 1.0));
    imageStore(u_y, p, vec4(y, 1.0));
    imageStore(u_t_prev, p, vec4(t, 1.0));
}
#endif
