"""The `torquelab` command line: serve (default), experiment, sweep, check, bench."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import robots


def _robot_arg(parser: argparse.ArgumentParser) -> None:
    add_robot_args(parser)


def add_robot_args(parser: argparse.ArgumentParser) -> None:
    """--robot NAME | --urdf PATH, and the chain and package options of a URDF."""
    group = parser.add_mutually_exclusive_group()
    names = ", ".join((*robots.BUILTIN, *robots.EXTERNAL))
    group.add_argument("--robot", default=None, help=f"robot by name: {names} (panda needs the robots extra)")
    group.add_argument("--urdf", default=None, help="path to a URDF holding a 7-DOF arm (sidecar .toml optional)")
    parser.add_argument("--base", default=None, metavar="LINK", help="with --urdf: the arm's base link (default: root)")
    parser.add_argument(
        "--tip", default=None, metavar="LINK", help="with --urdf: the arm's tip link (default: the only 7-joint chain)"
    )
    parser.add_argument(
        "--package-path",
        action="append",
        default=[],
        metavar="DIR",
        help="with --urdf: a folder holding package NAME of package://NAME/... meshes (repeatable)",
    )


def _robot_name(args: argparse.Namespace, default: str = robots.DEFAULT_ROBOT) -> str:
    return robots.spec_from_args(args) or default


def cmd_check(args: argparse.Namespace) -> int:
    from app.tools.check import cross_check

    names = [_robot_name(args)] if (args.robot or args.urdf) else list(robots.available())
    if not (args.robot or args.urdf):
        _robot_name(args)  # --base/--tip without --urdf is refused
    reports = [cross_check(robots.load(n), samples=args.samples) for n in names]
    if args.json:
        print(json.dumps(reports, indent=2))
    else:
        for rep in reports:
            status = "ok" if rep["ok"] else "FAIL"
            errs = "  ".join(f"{k} {v:.1e}" for k, v in rep["worst_relative_error"].items())
            print(
                f"{rep['robot']:10s} {status:4s}  worst relative error over {rep['samples']} states: {errs}"
                f"  (tolerance {rep['tolerance']:.0e})"
            )
    return 0 if all(r["ok"] for r in reports) else 1


def cmd_bench(args: argparse.Namespace) -> int:
    if getattr(args, "soak", None) is not None:
        from app.tools.soak import cmd_soak

        return cmd_soak(args)
    if getattr(args, "classroom", False):
        from app.tools.bench_classroom import cmd_bench_classroom

        return cmd_bench_classroom(args)
    if getattr(args, "serve", False):
        from app.tools.bench_serve import cmd_bench_serve

        return cmd_bench_serve(args)
    from app.tools.bench import run_bench

    report = run_bench(_robot_name(args), repeats=args.repeats, only=args.only, placo_python=args.vs_placo)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"robot {report['robot']}  (median / p95 µs, share of the 1 ms step)")
        for name, r in report["results"].items():
            print(
                f"  {name:34s} {r['median_us']:9.1f} {r['p95_us']:9.1f}   {100 * r['share_of_1ms']:5.1f} %"
                f"   ×{r['real_time_factor']:.1f} real time"
            )
        if "placo" in report:
            pl = report["placo"]
            print(f"  {'placo DynamicsSolver step':34s} {pl['step_us']:9.1f} {pl['p95_us']:9.1f}")
        for key, value in report["summary"].items():
            print(f"  {key}: {value:.2f}")
    return 0


def cmd_classroom(args: argparse.Namespace) -> int:
    from app.live.classroom.command import run_classroom

    return run_classroom(args)


def cmd_serve(args: argparse.Namespace) -> int:
    from app.live.server import serve

    return serve(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torquelab", description="Torque control lab for redundant arms")
    sub = parser.add_subparsers(dest="command")

    p = sub.add_parser("serve", help="start the web app (default)")
    _robot_arg(p)
    p.add_argument("--scenario", default="polish", help="polish, free, limit-drop, mass-drop, compliance")
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1, local only)")
    p.add_argument("--port", type=int, default=8080, help="TCP port (0: any free port; the URL printed says which)")
    p.add_argument(
        "--settings", default=None, metavar="FILE", help="TOML settings file to apply at start (one table per group)"
    )
    p.add_argument(
        "--no-warmup",
        dest="warm",
        action="store_false",
        help="skip compiling every kernel before the URL (the first steps then compile on the loop thread)",
    )
    p.add_argument(
        "--watch-only",
        action="store_true",
        help="every page sees the arm and steers nothing (its inputs are refused by the server)",
    )
    p.add_argument(
        "--steer-local",
        action="store_true",
        help="with --watch-only: pages opened on this machine steer, pages from other machines watch",
    )
    p.add_argument(
        "--seat", action="store_true", help=argparse.SUPPRESS
    )  # started by `classroom`: see app/live/classroom
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("classroom", help="one link for a class: each student an own lab (a seat), a teacher's view")
    _robot_arg(p)
    p.add_argument("--seats", type=int, default=4, help="labs that can run at once, one per student (default 4)")
    p.add_argument("--scenario", default="polish", help="the preset each seat starts on (default polish)")
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1, local only)")
    p.add_argument("--port", type=int, default=8080, help="the lobby's TCP port (0: any free port)")
    p.add_argument(
        "--idle", type=float, default=600.0, metavar="SECONDS", help="free a seat with no page open this long (600)"
    )
    p.set_defaults(func=cmd_classroom)

    p = sub.add_parser("check", help="cross-check Pinocchio against MuJoCo")
    _robot_arg(p)
    p.add_argument("--samples", type=int, default=100)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("bench", help="time the pieces of one control step")
    _robot_arg(p)
    p.add_argument("--repeats", type=int, default=300)
    p.add_argument("--only", nargs="*", default=None, help="benchmark names to run")
    p.add_argument("--serve", action="store_true", help="real-time factor of the web app with one headless browser")
    p.add_argument(
        "--classroom",
        action="store_true",
        help="seats' real-time factors and the frames their pages get, for several seat and watcher counts",
    )
    p.add_argument("--seat-counts", default="1,2,4,8", metavar="N,N,...", help="with --classroom (default 1,2,4,8)")
    p.add_argument(
        "--watcher-counts",
        default="1,10,30",
        metavar="K,K,...",
        help="with --classroom: watchers of one seat (none: no run)",
    )
    p.add_argument(
        "--chromium-pages",
        action="store_true",
        help="with --classroom: each seat's student a headless Chromium page (frames received and drawn, browser CPU)",
    )
    p.add_argument("--scenario", default="polish", help="scenario for --serve and --classroom (default polish)")
    p.add_argument(
        "--soak",
        type=float,
        default=None,
        metavar="MINUTES",
        help="memory slope of the web app over MINUTES with preset switches, drags and a headless browser",
    )
    p.add_argument("--no-browser", action="store_true", help="with --soak: no browser")
    p.add_argument("--pages", type=int, default=1, metavar="N", help="with --soak: N browsers on the page")
    p.add_argument("--junk", action="store_true", help="with --soak: a client that sends malformed frames too")
    p.add_argument("--no-switches", action="store_true", help="with --soak: no preset switches")
    p.add_argument("--no-drags", action="store_true", help="with --soak: no drags")
    p.add_argument(
        "--trim-every", type=float, default=0.0, metavar="SECONDS", help="with --soak: also trim the heap this often"
    )
    p.add_argument("--seconds", type=float, default=20.0, help="measuring time for --serve (wall seconds)")
    p.add_argument(
        "--twin", choices=("j", "f", "a", "d"), default=None, help="with --serve: also run a twin arm with this W"
    )
    p.add_argument(
        "--vs-placo",
        metavar="PYTHON",
        default=None,
        help="also time placo 0.10.2's DynamicsSolver with this Python (a venv with placo) and print the ratio",
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_bench)

    from app.headless.experiments import add_parsers

    add_parsers(sub)
    _add_sweep(sub)
    for name, command in sub.choices.items():
        if name != "check":
            _qp_backend_arg(command)
        if name in ("experiment", "sweep"):
            _leaves(command, add_robot_args)
    return parser


def _leaves(parser: argparse.ArgumentParser, add) -> None:
    """`add(parser)` on each leaf command under `parser` (a leaf's default would override a parent's)."""
    nested = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not nested:
        if not any("--robot" in a.option_strings for a in parser._actions):
            add(parser)
        return
    for action in nested:
        for command in action.choices.values():
            _leaves(command, add)


def _qp_backend_arg(parser: argparse.ArgumentParser) -> None:
    """--qp-backend on a command, or on each of its subcommands (a leaf's default would override it)."""
    from control.qp import BACKENDS, DEFAULT_BACKEND

    nested = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if nested:
        for action in nested:
            for command in action.choices.values():
                _qp_backend_arg(command)
        return
    parser.add_argument(
        "--qp-backend",
        choices=BACKENDS,
        default=None,
        help=f"QP solver of both executors (default {DEFAULT_BACKEND}: DAQP active set; osqp: the reference)",
    )


def _add_sweep(sub) -> None:
    from app.headless.sweep.cli import add_parser

    add_parser(sub)


# The counts and durations any command takes, and their least value: checked once, before the command runs
# (zero samples used to print "ok", zero repeats ended in a traceback).
COUNTS: dict[str, tuple[str, int]] = {
    "samples": ("--samples", 1),
    "repeats": ("--repeats", 1),
    "seeds": ("--seeds", 1),
    "jobs": ("--jobs", 1),
    "repetitions": ("--repetitions", 1),
    "held_repetitions": ("--held-repetitions", 0),
    "first_seed": ("--first-seed", 0),
    "pages": ("--pages", 1),
    "seats": ("--seats", 1),
}
DURATIONS: dict[str, tuple[str, str]] = {
    "seconds": ("--seconds", "seconds"),
    "duration": ("--duration", "seconds"),
    "soak": ("--soak", "minutes"),
    "idle": ("--idle", "seconds"),
}
MAX_COUNT = 10**7  # more than any run needs: a larger count is a typo, refused before it allocates


def check_counts(args: argparse.Namespace) -> None:
    """ValueError (one line) for a count below its least value or absurdly large, or a duration that is
    not a positive finite number."""
    for attr, (flag, least) in COUNTS.items():
        value = getattr(args, attr, None)
        if value is None:
            continue
        if value < least:
            raise ValueError(f"{flag} must be at least {least}, got {value}")
        if value > MAX_COUNT:
            raise ValueError(f"{flag} must be at most {MAX_COUNT:,}, got {value}")
    for attr, (flag, unit) in DURATIONS.items():
        value = getattr(args, attr, None)
        if value is None:
            continue
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{flag} must be a positive number of {unit}, got {value:g}")


def error_reason(exc: BaseException) -> str:
    """One non-empty line saying why a command failed (an empty message falls back to the type)."""
    text = " ".join(str(exc).split())
    if text:
        return text
    if isinstance(exc, TimeoutError):
        return "timed out waiting for the simulation loop"
    return type(exc).__name__


def load_chosen_robot(args: argparse.Namespace) -> None:
    """Load the arm of --urdf (and of experiment's and sweep's --robot) before the command runs: a wrong
    name or URDF is one line, a URDF's mesh files drawn as nothing are one line on stderr; experiment
    and sweep hand the arm to every session they build, workers included (ROBOT_ENV)."""
    spec = robots.spec_from_args(args)
    headless = args.command in ("experiment", "sweep")
    urdf = getattr(args, "urdf", None)
    if not spec or not (urdf or headless):
        return
    robot = robots.load(spec)
    if urdf:
        from robots.meshes import missing_meshes_line

        missing = missing_meshes_line(robot)  # visuals only: the dynamics are whole
        if missing:
            print(f"torquelab: {missing}", file=sys.stderr, flush=True)
    if headless:
        os.environ[robots.ROBOT_ENV] = spec


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help")):
        argv = ["serve", *argv]
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 0
    try:
        check_counts(args)
    except ValueError as exc:
        print(f"torquelab: error: {exc}", file=sys.stderr)
        return 2
    if args.command != "serve":  # serve loads its arm itself and says the same beside its URL
        try:
            load_chosen_robot(args)
        except (robots.RobotLoadError, ValueError) as exc:
            print(f"torquelab: error: {error_reason(exc)}", file=sys.stderr)
            return 2
    if getattr(args, "qp_backend", None):
        from control.qp import BACKEND_ENV

        os.environ[BACKEND_ENV] = args.qp_backend  # every executor built from now on, workers included
    try:
        return int(args.func(args) or 0)
    except (robots.RobotLoadError, ValueError, OSError) as exc:
        print(f"torquelab: error: {error_reason(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
