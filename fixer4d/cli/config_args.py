"""Arguments and config resolution shared by the pipeline's verbs (run, reconstruct, refine)."""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """--config, --set, --print-config."""
    parser.add_argument("--config", default=None, metavar="FILE",
                        help="a JSON config (a run's config.json or a partial tree) applied over the defaults")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="any config value by dotted key, e.g. --set training.iterations=800 (JSON values); "
                             "see --print-config for every key")
    parser.add_argument("--print-config", action="store_true",
                        help="print the resolved config (every key, validated) and exit without running")


class FormerFlag(argparse.Action):
    """A flag under its former name (hidden from --help): its value goes where the current flag's
    does, with a one-line note on stderr naming the current flag."""

    def __init__(self, option_strings, dest, current: str, **kwargs) -> None:
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)
        self.current = current

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"{parser.prog}: {option_string} is now called {self.current}; read as {self.current}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_keep_checkpoints_argument(parser: argparse.ArgumentParser) -> None:
    """--keep-checkpoints (``run_pipeline``'s ``keep_checkpoints``)."""
    parser.add_argument("--keep-checkpoints", action="store_true",
                        help="keep each stage's newest checkpoints (training.keep_checkpoints of them) after the stage's "
                             "outputs are written; by default a finished stage leaves none")


def add_paper_stage2_argument(parser: argparse.ArgumentParser) -> None:
    """--paper-stage2 (``paper_stage2_overrides``)."""
    parser.add_argument("--paper-stage2", action="store_true",
                        help="the paper's stage 2: restored targets on every pixel, no self-check, ungated "
                             "restoration rows (--set values given as well win)")


def paper_stage2_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """``pipeline.config.PAPER_STAGE2`` when --paper-stage2 was given, else nothing."""
    if not args.paper_stage2:
        return {}
    from fixer4d.pipeline.config import PAPER_STAGE2

    return dict(PAPER_STAGE2)


def frame_range_override(text: str | None) -> list[int] | None:
    """``--frames a:b`` (half-open, the scene's own frame numbers) -> [a, b], by the one frame-range
    parser (``fixer4d.scene.parse_frame_range``); checked against the scene's length when it opens."""
    if text is None:
        return None
    from fixer4d.scene import parse_frame_range

    return list(parse_frame_range(text))


def resolve_from_args(args: argparse.Namespace, flags: dict[str, Any], *, source: str | None = None,
                      forced: dict[str, Any] | None = None, base: dict[str, Any] | None = None):
    """The RunConfig of a verb: defaults (or ``base``, a run's own config) <- --config <- the
    verb's flags (``flags``: dotted key -> value, None = not given) <- --set <- ``forced``."""
    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline.config import resolve

    overrides = {k: v for k, v in flags.items() if v is not None}
    overrides.update(config_tree.parse_set_overrides(args.set))
    overrides.update(forced or {})
    return resolve(source, config_file=args.config, overrides=overrides, defaults=base)


def maybe_print_config(args: argparse.Namespace, config) -> bool:
    """Print the resolved config when --print-config was given; True when the verb should stop."""
    if not args.print_config:
        return False
    from fixer4d.pipeline.config import FORMAT_VERSION

    print(json.dumps({"format_version": FORMAT_VERSION, "config": config.to_dict()}, indent=2))
    return True
