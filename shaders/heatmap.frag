#version 330 core
// Resolve the accumulated splat targets into a displayable image, optionally as a debug map:
// 0 colour over the background, 1 hole map (low accumulated alpha in red over the colour),
// 2 expected depth (turbo, near..far), 3 an uploaded scalar map (blur, undetermined) in turbo over grey,
// 4 accumulated alpha as grey, 5 an uploaded mask (moving content) tinted magenta over the colour.
uniform sampler2D u_color;   // premultiplied rgb, accumulated alpha
uniform sampler2D u_depth;   // alpha-weighted depth in r, alpha in a
uniform sampler2D u_scalar;  // R32F, modes 3 and 5
uniform vec3 u_background;
uniform int u_mode;
uniform float u_hole_alpha;  // accumulated alpha below which a pixel counts as a hole
uniform vec2 u_depth_range;  // near, far for the depth colormap
uniform float u_scalar_max;

// Less accumulated alpha than one splat's minimum (1/255): nothing was drawn there.
const float EMPTY_ALPHA = 1.0 / 255.0;

in vec2 v_uv;
out vec4 frag;

void main() {
    vec4 c = texture(u_color, v_uv);
    vec3 rgb = c.rgb + (1.0 - c.a) * u_background;
    if (u_mode == 1) {
        float hole = clamp((u_hole_alpha - c.a) / max(u_hole_alpha, 1e-6), 0.0, 1.0);
        rgb = mix(rgb, vec3(1.0, 0.0, 0.0), c.a < u_hole_alpha ? 0.35 + 0.65 * hole : 0.0);
    } else if (u_mode == 2) {
        vec4 d = texture(u_depth, v_uv);
        float z = d.a >= EMPTY_ALPHA ? d.r / d.a : 0.0;
        float x = (z - u_depth_range.x) / max(u_depth_range.y - u_depth_range.x, 1e-6);
        rgb = d.a >= EMPTY_ALPHA ? turbo(1.0 - x) : vec3(0.0);
    } else if (u_mode == 3) {
        float s = texture(u_scalar, v_uv).r / max(u_scalar_max, 1e-6);
        rgb = mix(vec3(dot(rgb, vec3(0.299, 0.587, 0.114))), turbo(s), clamp(s * 2.0, 0.0, 1.0));
    } else if (u_mode == 4) {
        rgb = vec3(c.a);
    } else if (u_mode == 5) {
        rgb = mix(rgb, vec3(1.0, 0.2, 0.9), 0.6 * clamp(texture(u_scalar, v_uv).r, 0.0, 1.0));
    }
    frag = vec4(clamp(rgb, 0.0, 1.0), 1.0);
}
