"""The ``wmr-jax`` command line: every user error is one line on stderr and exit status 2.

Each command's module has ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Sequence

# The commands in --help order, and their help. Each is the add_arguments and the
# run_<name> (else run) of the cli module of its name; demo's is paper's.
_HELP = {
    "simulate": "drive the robot to one reference pose and report",
    "demo": "the main job: reproduce the paper into a folder, tabulate",
    "paper": "Figs. 6-10, wheel speeds and the paper table",
    "tune": "tune gains by gradient descent under k_r + L k_theta <= V_max",
    "sweep": "map success, arrival, path, wheel speed and zig-zag over a pose space",
    "compare": "compare the controllers over random poses (the table of docs/maps.md)",
    "waypoints": "consecutive motions through a chain of waypoints",
    "robustness": "Monte Carlo of noise, model mismatch and latency",
    "evaluate": "judge tuned gains (and their estimator) on your references under one condition",
    "export": "write a tuned loop (law, estimator, latency compensation) as a C controller",
    "animate": "animated GIF of a batch of robots driving to their poses",
    "identify": "fit the true robot (wheel scales, track, wheel lag, latency, noise) to its logs",
    "bench": "robot-steps per second against NumPy baselines",
}
COMMANDS = tuple(_HELP)

# Sweep-like commands spread their batches over every local device; on a CPU
# that means splitting it into several JAX devices first (wmr_jax.studies.use_cpu_devices).
_ALL_DEVICE_COMMANDS = ("sweep", "compare", "bench")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show every default that is a value; mark required flags; leave switches alone."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if action.required:
            return text + " (required)"
        # Identity, not equality: a default of 0 is worth showing, False is not.
        hidden = action.default is None or action.default is False
        said = "%(default)" in text or "(default:" in text  # the help states it itself
        if hidden or action.default is argparse.SUPPRESS or said:
            return text
        if isinstance(action.default, (list, tuple)):
            # Several values are shown as they are typed: "0 0 0", not "['0', '0', '0']".
            return f"{text} (default: {' '.join(map(str, action.default))})"
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line, like every other error."""

    def error(self, message: str):
        # One prefix for every error, the parser's as the commands' own.
        self.exit(2, f"wmr-jax: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``wmr-jax``."""
    parser = _Parser(
        prog="wmr-jax",
        description="Differentiable, batched simulator of the Shim–Sung (2003) pose controller.",
        formatter_class=_HelpFormatter,
        # A flag is spelled whole: a prefix of one flag must not quietly be another.
        allow_abbrev=False,
    )
    parser.add_argument("--version", action="version", version=f"wmr-jax {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parser.commands = {}  # name -> its parser, whose errors name its own --help
    for name, text in _HELP.items():
        module = importlib.import_module(f"wmr_jax._src.cli.{'paper' if name == 'demo' else name}")
        command = sub.add_parser(
            name, help=text, description=text, formatter_class=_HelpFormatter, allow_abbrev=False
        )
        module.add_arguments(command)
        parser.commands[name] = command
        command.set_defaults(func=getattr(module, f"run_{name}", None) or module.run)
    return parser


def _version() -> str:
    """Return the installed version of the package (its own ``__version__`` if not installed)."""
    from importlib import metadata

    try:
        return metadata.version("wmr_jax")
    except metadata.PackageNotFoundError:  # run from a source tree
        from wmr_jax import __version__

        return __version__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:
        # No command is a usage error (status 2), shown with the whole help.
        parser.print_help(sys.stderr)
        return 2
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # a flag the command does not have: its own --help lists them
        top = unknown[0] in argv and argv.index(unknown[0]) < argv.index(args.command)
        which = parser if top else parser.commands[args.command]
        which.error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.command in _ALL_DEVICE_COMMANDS and getattr(args, "cpu_devices", None) is None:
        from wmr_jax._src.sim.sharding import use_cpu_devices

        # Before any JAX computation; a no-op on accelerators. A command with
        # its own --cpu-devices flag splits the CPU itself, after checking it.
        use_cpu_devices()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = _one_line_warning
            return args.func(args)
    except ValueError as err:
        print(f"wmr-jax: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a disk that fills or a folder that vanishes mid-run
        from wmr_jax._src.io import os_reason

        print(f"wmr-jax: error: {os_reason(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # tune (any mode) and sweep can continue.
        hint = " (the same command with --resume keeps what it finished)"
        hint = hint if hasattr(args, "resume") else ""
        if args.command == "bench" and args.json is not None:
            hint = f" ({args.json} holds the batch sizes it finished)"
        print(f"wmr-jax: interrupted{hint}", file=sys.stderr)
        return 130


_shown_warnings: set[str] = set()


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Print each distinct warning once, in one line."""
    text = str(message)
    if text not in _shown_warnings:
        _shown_warnings.add(text)
        print(f"wmr-jax: warning: {text}", file=sys.stderr)


def entry() -> None:
    """The ``wmr-jax`` program: ``main``, then exit with its status.

    After an interruption (130) the process ends at once: tearing the interpreter
    down under JAX's threads could crash it and hide the status.
    """
    status = main()
    if status == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    sys.exit(status)


if __name__ == "__main__":
    entry()
