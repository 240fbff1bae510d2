"""Headless experiments that reproduce the papers' studies and write a report.

Each experiment module registers itself in `EXPERIMENTS` with a function that adds its options
to an argparse sub-parser and a `run(args) -> int`.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable

from app.headless.experiments.run_config import parse_settings

# experiment name -> module under app.headless.experiments providing `add_arguments(parser)` and `run(args)`
EXPERIMENTS: dict[str, str] = {
    "polish": "polish",
    "limit-drop": "limit_drop",
    "mass-drop": "mass_drop",
    "compliance": "compliance",
}


def add_parsers(sub) -> None:
    """Add `torquelab experiment NAME` with one sub-command per registered experiment."""
    p = sub.add_parser("experiment", help="run a paper experiment headless and write a report")
    exp_sub = p.add_subparsers(dest="experiment")
    for name, module_name in EXPERIMENTS.items():
        module = importlib.import_module(f"app.headless.experiments.{module_name}")
        ep = exp_sub.add_parser(name, help=(module.__doc__ or "").strip().splitlines()[0])
        ep.add_argument("--out", default=f"out/{name}", help="output directory")
        ep.add_argument("--json", action="store_true", help="print the results as JSON")
        ep.add_argument("--jobs", type=int, default=1, help="parallel runs over processes")
        ep.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="GROUP.FIELD=VALUE",
            help="a session parameter every run starts with, through the parameter path (repeatable), "
            "e.g. --set sensor.cutoff_hz=10 --set world.armature_scale=2",
        )
        module.add_arguments(ep)
        ep.set_defaults(func=_with_checked_jobs(module.run))
    p.set_defaults(func=lambda args: _no_experiment(p))


def _with_checked_jobs(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """`run`, refusing a --jobs below 1 first (ValueError: one line at the command line)."""

    def checked(args: argparse.Namespace) -> int:
        if args.jobs < 1:
            raise ValueError(f"--jobs must be at least 1, got {args.jobs}")
        parse_settings(args.set)  # a malformed --set is one line before anything runs
        return run(args)

    return checked


def _no_experiment(parser: argparse.ArgumentParser) -> int:
    names = ", ".join(EXPERIMENTS) or "none yet"
    print(f"choose an experiment: {names}")
    return 2
