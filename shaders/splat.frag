#version 330 core
// Front-to-back compositing of one Gaussian's fragment (blend: src*(1-dst_alpha) + dst).
// Outputs premultiplied colour and, in a second target, alpha-weighted z-depth; the same rules
// as the torch rasterizer (fixer4d/render/reference.py): skipped outside the 3-sigma ellipse,
// alpha = min(max_alpha, opacity * exp(power)), skipped below min_alpha. Only the early stop at
// transmittance < T_MIN has no blend-equation counterpart (its effect is below 8-bit precision).

uniform float u_min_alpha;
uniform float u_max_alpha;
uniform float u_power_max;  // 0.5 * Mahalanobis^2 beyond which a pixel is outside the splat

in vec2 v_offset;
flat in vec3 v_conic;
flat in vec4 v_color;
flat in float v_depth;

layout(location = 0) out vec4 out_color;
layout(location = 1) out vec4 out_depth;

void main() {
    vec2 d = v_offset;
    float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;
    if (power > 0.0 || -power > u_power_max) discard;
    float alpha = min(u_max_alpha, v_color.a * exp(power));
    if (alpha < u_min_alpha) discard;
    out_color = vec4(v_color.rgb * alpha, alpha);
    out_depth = vec4(v_depth * alpha, 0.0, 0.0, alpha);
}
