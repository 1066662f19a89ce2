"""Shader loading: GLSL sources live in the repository's shaders/ folder."""
from __future__ import annotations

from pathlib import Path

import moderngl

from fixer4d.errors import InputError

SHADER_DIR = Path(__file__).resolve().parents[2] / "shaders"


def shader_source(name: str) -> str:
    """The text of shaders/<name>, with shaders/colormap.glsl inserted after its #version line."""
    path = SHADER_DIR / name
    if not path.is_file():
        raise InputError(f"shader {path} is missing; run the viewer from a fixer4d checkout (pip install -e .)")
    text = path.read_text()
    head, _, rest = text.partition("\n")
    if not head.startswith("#version"):
        raise InputError(f"shader {path} must start with a #version line")
    return f"{head}\n{(SHADER_DIR / 'colormap.glsl').read_text()}\n{rest}"


def load_program(ctx: moderngl.Context, vert: str, frag: str) -> moderngl.Program:
    """Compile shaders/<vert> + shaders/<frag> into a program."""
    return ctx.program(vertex_shader=shader_source(vert), fragment_shader=shader_source(frag))
