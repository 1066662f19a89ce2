#version 330 core
// World-space line segments (frusta, trajectory paths) drawn with the viewer camera's
// K-exact OpenGL projection.
uniform mat4 u_mvp;
uniform float u_point_size;  // pixels, for POINTS draws (camera markers)
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec4 a_color;
out vec4 v_color;
void main() {
    v_color = a_color;
    gl_Position = u_mvp * vec4(a_pos, 1.0);
    gl_PointSize = u_point_size;
}
