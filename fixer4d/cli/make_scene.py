"""`fixer4d make-scene SPEC --out DIR --format n3dv`: write a synthetic scene to disk."""
from __future__ import annotations

import argparse


def _check_llff_scale(scene, spec: str, scale: float) -> None:
    """The Neural3DV layout stores one focal and a centred principal point per camera; a scale that
    rounds the image to a size breaking that is refused with scales near it that work."""
    from fixer4d.errors import InputError
    from fixer4d.geometry.llff import llff_compatible
    from fixer4d.scene.synthetic import SyntheticScene

    if all(llff_compatible(c) for c in scene.cameras):
        return
    rig = SyntheticScene(spec).cameras
    near = sorted({round(scale * d) / d for d in (4, 8, 16, 32) if round(scale * d) > 0}, key=lambda s: abs(s - scale))
    good = [s for s in near if all(llff_compatible(c.scaled(s)) for c in rig)][:3]
    c = scene.cameras[0]
    raise InputError(f"--scale {scale}: the {c.width}x{c.height} images it gives do not keep square pixels and a centred "
                     "principal point, which the Neural3DV layout (poses_bounds.npy) needs"
                     + (f"; scales near it that do: {', '.join(f'{s:g}' for s in good)}" if good else ""))


def _crf(text: str) -> int:
    """argparse type: x264's constant-rate factor, 0..51."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number in 0..51") from None
    if not 0 <= value <= 51:
        raise argparse.ArgumentTypeError(f"{value}: x264's CRF is 0 (lossless) .. 51 (worst)")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="scene spec: 'demo', another bundled name (tiny, static_matte) or a .json path")
    parser.add_argument("--out", required=True, help="output folder (replaced atomically if it exists)")
    parser.add_argument("--format", default="n3dv", choices=["n3dv"],
                        help="on-disk layout: n3dv = camXX.mp4 + poses_bounds.npy + depth/ + scene.json")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the rig (0.5 = half resolution)")
    parser.add_argument("--frames", type=int, nargs=2, metavar=("A", "B"), default=None,
                        help="keep spec frames A..B-1 only")
    parser.add_argument("--supersample", type=int, default=None, help="k x k rays per pixel (default: the spec's)")
    parser.add_argument("--crf", type=_crf, default=None, metavar="0..51",
                        help="x264 constant-rate factor (default 12, 0 = lossless, 51 = worst)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from fixer4d.scene.export import export_n3dv
    from fixer4d.scene.synthetic import SyntheticScene
    from fixer4d.scene.video import VIDEO_CRF

    scene = SyntheticScene(args.spec, scale=args.scale, frame_range=tuple(args.frames) if args.frames else None,
                           supersample=args.supersample)
    _check_llff_scale(scene, args.spec, args.scale)
    out = export_n3dv(scene, args.out, crf=VIDEO_CRF if args.crf is None else args.crf, progress=not args.no_progress)
    print(f"{scene.describe()} -> {out} ({args.format})")
    return 0
