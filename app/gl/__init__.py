"""OpenGL (moderngl, GL 3.3 core) drawing for the viewer: splats, overlays, shader loading."""
