// The fullscreen triangle: three vertices from gl_VertexID alone (no vertex buffer; draw with
// vrcorrect.runtime.gl.fullscreen_triangle). Clip-space corners (-1,-1), (3,-1), (-1,3) cover
// the viewport; uv runs from 0 to 1 across it in OpenGL's orientation, v = 0 at the bottom.
// vrcorrect.runtime.gl.upload_texture stores images bottom row first, so a texture sampled at
// uv appears upright (see "Orientation" in vrcorrect/runtime/gl.py).
#ifndef VRCORRECT_FULLSCREEN_GLSL
#define VRCORRECT_FULLSCREEN_GLSL

// uv of vertex 0, 1, 2: (0, 0), (2, 0), (0, 2).
vec2 fullscreen_uv(int vertex_id) {
    return vec2(float((vertex_id << 1) & 2), float(vertex_id & 2));
}

vec4 fullscreen_position(vec2 uv) {
    return vec4(uv * 2.0 - 1.0, 0.0, 1.0);
}

#endif
