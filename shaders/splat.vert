#version 330 core
// Spacetime Gaussian splats as instanced screen-space quads (DESIGN.md §4-5): each instance is
// one Gaussian already evaluated at the current time and projected by splat_prep.vert (centre,
// quad half-size, inverse 2D covariance, colour and opacity), in front-to-back order; here only
// the quad's corner is placed, in OpenCV pixel coordinates with pixel centres at +0.5.

uniform vec2 u_size;           // W, H (pixels)

layout(location = 0) in vec4 i_center;  // x, y (pixels), half-size (0 = culled), camera z
layout(location = 1) in vec4 i_conic;   // inverse 2D covariance (a, b, c), opacity
layout(location = 2) in vec4 i_color;   // rgb

out vec2 v_offset;     // pixel offset of this corner from the projected centre
flat out vec3 v_conic; // inverse 2D covariance (a, b, c)
flat out vec4 v_color; // rgb, opacity at u_time
flat out float v_depth;

void main() {
    if (i_center.z <= 0.0) {
        gl_Position = vec4(0.0, 0.0, 2.0, 1.0);  // outside the clip volume: no fragments
        v_offset = vec2(0.0); v_conic = vec3(0.0); v_color = vec4(0.0); v_depth = 0.0;
        return;
    }
    vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
    vec2 pix = i_center.xy + corner * i_center.z;
    v_offset = pix - i_center.xy;
    v_conic = i_conic.xyz;
    v_color = vec4(i_color.rgb, i_conic.w);
    v_depth = i_center.w;
    gl_Position = vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
}
