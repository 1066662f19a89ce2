#version 330 core
// Splat preparation pass, run once per Gaussian (in depth order) with transform feedback: the
// result feeds splat.vert's instanced screen-space quads (DESIGN.md §4-5). Doing the Gaussian's
// work once instead of in each of its quad's 4 vertices cuts the vertex cost 4x (on a software
// GL it dominates a reduced-resolution frame).
// Per-Gaussian raw parameters live in an RGBA32F texture, TEXELS texels per Gaussian, read with
// texelFetch (GL 3.3 data path). The spacetime terms are evaluated here at u_time; the 3D
// covariance is projected with the EWA Jacobian plus the rasterizer's low-pass, exactly as the
// torch rasterizer does, in OpenCV pixel coordinates with pixel centres at +0.5.

#define MAX_SH_TEXELS 12       // degree 3: 15 coefficients x 3 channels = 45 floats
uniform sampler2D u_params;    // RGBA32F, width u_tex_width texels, u_texels per Gaussian
uniform int u_texels;          // 8 + the SH texels
uniform int u_sh_degree;       // 0..3: higher SH bands after the 8 base texels
uniform vec3 u_cam_center;     // world position of the camera (view direction for SH)
uniform sampler2D u_flags;     // R32F, one texel per Gaussian: 1 = selected
uniform int u_tex_width;
uniform mat4 u_w2c;            // world -> camera (OpenCV axes), column-major
uniform vec4 u_intr;           // fx, fy, cx, cy (pixels)
uniform vec2 u_size;           // W, H (pixels)
uniform float u_time;
uniform float u_t_log_scale_min; // the model's clamp of t_log_scale (exp stays finite)
uniform float u_det_min;       // smallest 2D covariance determinant that is inverted
uniform float u_near;          // near plane (camera z)
uniform float u_lowpass;       // added to the 2D covariance diagonal (px^2)
uniform float u_min_alpha;     // below this the Gaussian cannot contribute
uniform float u_sigma_extent;  // quad half-size in standard deviations
uniform float u_fov_clamp;     // Jacobian tangents clamped to the fov widened by this fraction of tan(fov/2)
uniform int u_mode;            // 0 colour, 1 speed heat, 2 temporal-opacity heat
uniform float u_heat_scale;    // speed that maps to the top of the colormap
uniform int u_show_selection;
uniform float u_lod_area;      // level of detail: 2D covariance scale of a kept splat (1 = exact)

layout(location = 0) in uint a_index;   // per instance: the Gaussian, in depth order

out vec4 f_center;     // projected centre x, y (pixels), quad half-size (0 = culled), camera z
out vec4 f_conic;      // inverse 2D covariance (a, b, c), opacity at u_time
out vec4 f_color;      // rgb (w unused)

vec4 fetch(int i, int k) {
    int texel = i * u_texels + k;
    return texelFetch(u_params, ivec2(texel % u_tex_width, texel / u_tex_width), 0);
}

mat3 quat_to_mat(vec4 q) {  // q = (w, x, y, z), normalized here, zero -> identity
    float n = length(q);
    q = n < 1e-12 ? vec4(1.0, 0.0, 0.0, 0.0) : q / n;
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // GLSL mat3 is column-major: each vec3 is a column.
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

// Real SH constants (fixer4d.model.spacetime SH_C0..SH_C3, the 3DGS convention).
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                                -0.4570457994644658, 1.445305721320277, -0.5900435899266435);

// Colour before the +0.5 offset from the higher SH bands of Gaussian i seen along unit dir d,
// as fixer4d.model.spacetime.sh_basis (coefficient k of channel c at float 3k + c).
vec3 sh_rest(int i, vec3 d) {
    vec4 t[MAX_SH_TEXELS];
    int n = (3 * ((u_sh_degree + 1) * (u_sh_degree + 1) - 1) + 3) / 4;
    for (int j = 0; j < MAX_SH_TEXELS; ++j) t[j] = j < n ? fetch(i, 8 + j) : vec4(0.0);
    float f[4 * MAX_SH_TEXELS];
    for (int j = 0; j < MAX_SH_TEXELS; ++j) {
        f[4 * j] = t[j].x; f[4 * j + 1] = t[j].y; f[4 * j + 2] = t[j].z; f[4 * j + 3] = t[j].w;
    }
    float x = d.x, y = d.y, z = d.z;
    float b[15];
    b[0] = -SH_C1 * y; b[1] = SH_C1 * z; b[2] = -SH_C1 * x;
    int K = 3;
    if (u_sh_degree > 1) {
        float xx = x * x, yy = y * y, zz = z * z;
        b[3] = SH_C2[0] * x * y; b[4] = SH_C2[1] * y * z; b[5] = SH_C2[2] * (2.0 * zz - xx - yy);
        b[6] = SH_C2[3] * x * z; b[7] = SH_C2[4] * (xx - yy);
        K = 8;
        if (u_sh_degree > 2) {
            b[8] = SH_C3[0] * y * (3.0 * xx - yy); b[9] = SH_C3[1] * x * y * z;
            b[10] = SH_C3[2] * y * (4.0 * zz - xx - yy); b[11] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[12] = SH_C3[4] * x * (4.0 * zz - xx - yy); b[13] = SH_C3[5] * z * (xx - yy);
            b[14] = SH_C3[6] * x * (xx - 3.0 * yy);
            K = 15;
        }
    }
    vec3 rgb = vec3(0.0);
    for (int k = 0; k < K; ++k) rgb += b[k] * vec3(f[3 * k], f[3 * k + 1], f[3 * k + 2]);
    return rgb;
}

void cull() {
    f_center = vec4(0.0); f_conic = vec4(0.0); f_color = vec4(0.0);  // radius 0: splat.vert culls
}

void main() {
    int i = int(a_index);
    vec4 p0 = fetch(i, 0);  // mean.xyz, opacity logit
    vec4 p1 = fetch(i, 1);  // log_scale.xyz, t_center
    vec4 q0 = fetch(i, 2);  // quat wxyz
    vec4 p3 = fetch(i, 3);  // colour DC rgb, t_log_scale
    vec4 p4 = fetch(i, 4);  // m1.xyz, dynamic
    vec4 p5 = fetch(i, 5);  // m2.xyz
    vec4 p6 = fetch(i, 6);  // m3.xyz
    vec4 om = fetch(i, 7);  // omega wxyz

    bool dynamic = p4.w > 0.5;
    float dt = dynamic ? u_time - p1.w : 0.0;
    vec3 mean = p0.xyz + dt * (p4.xyz + dt * (p5.xyz + dt * p6.xyz));
    vec4 q = q0 + om * dt;
    float tx_ = dt * exp(-max(p3.w, u_t_log_scale_min));
    float t_factor = exp(-tx_ * tx_);
    float opacity = t_factor / (1.0 + exp(-p0.w));
    if (opacity < u_min_alpha) { cull(); return; }   // temporally absent at this time

    vec3 pc = (u_w2c * vec4(mean, 1.0)).xyz;
    if (pc.z <= u_near) { cull(); return; }

    mat3 R = quat_to_mat(q);
    vec3 s = exp(p1.xyz);
    mat3 M = R * mat3(s.x, 0.0, 0.0, 0.0, s.y, 0.0, 0.0, 0.0, s.z);
    mat3 cov3 = M * transpose(M);
    mat3 W = mat3(u_w2c);
    mat3 covc = W * cov3 * transpose(W);

    float fx = u_intr.x, fy = u_intr.y, cx = u_intr.z, cy = u_intr.w;
    // Clamp the Jacobian's evaluation point to the widened view frustum, as 3DGS/gsplat do, so
    // Gaussians far outside the image do not get huge screen-space footprints.
    float tan_x = 0.5 * u_size.x / fx, tan_y = 0.5 * u_size.y / fy;
    float lim_xp = (u_size.x - cx) / fx + u_fov_clamp * tan_x;
    float lim_xn = cx / fx + u_fov_clamp * tan_x;
    float lim_yp = (u_size.y - cy) / fy + u_fov_clamp * tan_y;
    float lim_yn = cy / fy + u_fov_clamp * tan_y;
    float tx = pc.z * clamp(pc.x / pc.z, -lim_xn, lim_xp);
    float ty = pc.z * clamp(pc.y / pc.z, -lim_yn, lim_yp);
    float iz = 1.0 / pc.z;
    // J (2x3) stored as the columns of a mat3x2 (GLSL: 3 columns of vec2).
    mat3x2 J = mat3x2(fx * iz, 0.0, 0.0, fy * iz, -fx * tx * iz * iz, -fy * ty * iz * iz);
    mat2 cov2 = u_lod_area * (J * covc * transpose(J));
    float a = cov2[0][0] + u_lowpass;
    float b = cov2[0][1];
    float c = cov2[1][1] + u_lowpass;
    float det = a * c - b * b;
    if (!(det > u_det_min)) { cull(); return; }
    float mid = 0.5 * (a + c);
    float lambda = mid + sqrt(max(0.0, mid * mid - det));
    float radius = ceil(u_sigma_extent * sqrt(lambda));

    vec2 center = vec2(fx * pc.x * iz + cx, fy * pc.y * iz + cy);   // continuous pixel coords
    if (center.x + radius <= 0.0 || center.x - radius >= u_size.x ||
        center.y + radius <= 0.0 || center.y - radius >= u_size.y) { cull(); return; }

    vec3 conic = vec3(c, -b, a) / det;
    vec3 rgb = 0.28209479177387814 * p3.xyz;
    if (u_sh_degree > 0) {
        // view direction from the camera centre to the mean at u_time (eps as DIRECTION_EPS)
        vec3 dir = mean - u_cam_center;
        rgb += sh_rest(i, dir / sqrt(dot(dir, dir) + 1e-12));
    }
    rgb = max(rgb + 0.5, 0.0);
    if (u_mode == 1) {
        vec3 vel = p4.xyz + 2.0 * dt * p5.xyz + 3.0 * dt * dt * p6.xyz;
        rgb = turbo(dynamic ? length(vel) / max(u_heat_scale, 1e-12) : 0.0);
    } else if (u_mode == 2) {
        rgb = turbo(t_factor);
    }
    if (u_show_selection == 1) {
        int texel = i;
        float sel = texelFetch(u_flags, ivec2(texel % u_tex_width, texel / u_tex_width), 0).r;
        if (sel > 0.5) rgb = mix(rgb, vec3(1.0, 0.2, 0.9), 0.7);
    }
    f_center = vec4(center, radius, pc.z);
    f_conic = vec4(conic, opacity);
    f_color = vec4(rgb, 0.0);
}
