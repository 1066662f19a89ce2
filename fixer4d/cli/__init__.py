"""The `fixer4d` command line: a thin dispatcher.

Each verb is a module of this package, above the library it drives, with two functions:
``add_arguments(parser)`` and ``run(args) -> int``. This file only lists them, so adding a verb
never touches another verb's code, and `fixer4d --help` imports nothing heavy. The library
below parses no arguments and never imports this package.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from fixer4d import numerics
from fixer4d.errors import Fixer4DError, InputError, Terminated

# verb -> (module, one-line help)
VERBS: dict[str, tuple[str, str]] = {
    "run": ("fixer4d.cli.run", "the whole method: poses -> init -> stage 1 -> (restore -> refine) x R -> evaluate"),
    "reconstruct": ("fixer4d.cli.reconstruct", "stage 1: STGS on the four observed views from a sparse or MVS init"),
    "refine": ("fixer4d.cli.refine", "stage 2: restoration-guided refinement of a reconstructed run"),
    "eval": ("fixer4d.cli.eval", "evaluate a run folder on the held-out cameras"),
    "init": ("fixer4d.cli.init", "per-frame point clouds: sparse (COLMAP) or dense (MVS)"),
    "trajectories": ("fixer4d.cli.trajectories", "pair trajectories and arcs of a scene's train cameras -> presets"),
    "calibrate": ("fixer4d.cli.calibrate", "the rig of a capture folder: from a ChArUco board filmed by its cameras, else from its own frames -> rig.json"),
    "make-scene": ("fixer4d.cli.make_scene", "write a synthetic scene spec to disk in the Neural3DV layout"),
    "study": ("fixer4d.cli.study", "accuracy vs time: sweep the pipeline's knobs, draw the Pareto front"),
    "bench": ("fixer4d.cli.bench", "benchmarks that print and save their numbers (raycast, raster, train-step, ...)"),
    "export": ("fixer4d.cli.export", "convert a model (.ply/.npz) or a run's latest model"),
    "render": ("fixer4d.cli.render", "a video or PNG frames of a model along a camera path, rig camera or trajectory"),
    "fetch-lpips": ("fixer4d.cli.fetch_lpips", "download the LPIPS-alex weights the metrics use (make setup runs it)"),
}


# verbs whose finished work survives an interruption and is reused by the same command
RESUMABLE = frozenset({"run", "reconstruct", "refine", "study"})


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fixer4d", description="Four synchronized cameras -> spacetime Gaussians, with the unseen views repaired "
                                    "(4DGS-Fixer). `fixer4d VERB --help` for each verb.")
    parser.add_argument("--version", action="version", version=_version())
    parser.add_argument("--numerics", choices=("portable", "host"), default=None,
                        help="portable (default): the same digits on any x86-64 CPU; host: each library's fastest "
                             "code paths for this CPU (digits depend on it; the same as FIXER4D_NUMERICS=host)")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for verb, (module, help_text) in VERBS.items():
        p = sub.add_parser(verb, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("fixer4d"):
                p.set_defaults(_missing=str(exc))
                continue
            raise
        mod.add_arguments(p)
    return parser


def _version() -> str:
    from fixer4d import __version__

    return f"fixer4d {__version__}"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.verb:
        parser.print_help()
        return 2
    if getattr(args, "_missing", None):
        print(f"fixer4d {args.verb}: not available in this build ({args._missing})", file=sys.stderr)
        return 2
    if args.numerics is not None and args.numerics != numerics.in_effect():
        _restart_with_numerics(args.numerics, argv)
    try:
        numerics.mode()
    except ValueError as exc:
        print(f"fixer4d: error: {exc} (or unset it)", file=sys.stderr)
        return 2
    if numerics.in_effect() != "portable":
        print(f"fixer4d: {numerics.describe()}", file=sys.stderr)
    else:
        from fixer4d.mkl_vendor import unpinned_warning

        if (warning := unpinned_warning()) is not None:
            print(f"fixer4d: {warning}", file=sys.stderr)
    from fixer4d.signals import install_sigterm

    install_sigterm()
    mod = importlib.import_module(args._module)
    try:
        return int(mod.run(args) or 0)
    except InputError as exc:  # bad input or config: the user can fix it; nothing was run
        _error(args.verb, exc)
        return 2
    except Fixer4DError as exc:
        _error(args.verb, exc)
        return 1
    except OSError as exc:  # the system refused a read or write: a full disk, a folder that cannot be made
        where = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        _error(args.verb, f"{exc.strerror or exc}{': ' + where if where else ''} ({type(exc).__name__}); "
                          "check that the folder exists, is writable and has space")
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM as errors.Terminated
        return _interrupted(args.verb, exc)
    except SystemError as exc:  # an interrupt raised inside a numba kernel arrives wrapped
        from fixer4d.signals import interrupt_behind

        inner = interrupt_behind(exc)
        if inner is None:
            raise
        return _interrupted(args.verb, inner)


def _error(verb: str, exc: Exception | str) -> None:
    """The one error line, on a line of its own: a progress bar the error stopped is closed first
    (its last state stays above), so the message never follows a bar's text."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):
        bar.close()
    print(f"fixer4d {verb}: error: {exc}", file=sys.stderr)


def _restart_with_numerics(mode: str, argv: list[str]) -> None:
    """Run this command again in a fresh process under numerics ``mode``: the libraries read their
    code-path pins once, when they load (``fixer4d.numerics``), so a running process cannot switch."""
    import os

    os.environ[numerics.ENV_MODE] = mode
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, "-m", "fixer4d.cli", *argv])


def _interrupted(verb: str, exc: KeyboardInterrupt) -> int:
    """One line for a Ctrl-C (exit 130) or a SIGTERM (exit 143), saying whether a rerun resumes."""
    what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
    resume = "; completed stages are saved and a rerun resumes" if verb in RESUMABLE else ""
    print(f"\nfixer4d {verb}: {what}{resume}", file=sys.stderr)
    return 143 if isinstance(exc, Terminated) else 130

