"""The ``mjxcpg`` command line: walk, learn, sweep, controls, eval, transfer, render, bench.

MuJoCo is imported only inside the commands (and the parser), so that ``render`` can choose
its headless OpenGL back end (``MUJOCO_GL``) before MuJoCo reads it, at import."""

from __future__ import annotations

import json
import logging
import os
import sys

from mjxcpg.cli.commands import UserError
from mjxcpg.cli.parser import build_parser

__all__ = ["main", "entry", "build_parser", "UserError"]


def _choose_headless_gl(argv: list[str]) -> None:
    """Before MuJoCo is imported: give ``render`` a headless OpenGL unless MUJOCO_GL is set."""
    if argv[:1] != ["render"] or "MUJOCO_GL" in os.environ or "mujoco" in sys.modules:
        return
    from mjxcpg.evaluation.render import headless_gl_backend

    backend = headless_gl_backend()
    if backend is not None:
        os.environ["MUJOCO_GL"] = backend


def _print_result(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result))
    else:
        width = max(map(len, result))
        for key, value in result.items():
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _choose_headless_gl(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    # Orbax logs what its writer threads meet with tracebacks; the errors reach the user as
    # one line each, from the library.
    logging.getLogger("absl").setLevel(logging.CRITICAL)
    try:
        result = args.handler(args)
    except (UserError, ValueError, OSError) as error:  # OSError: a full disk, a missing file, ...
        print(f"mjxcpg: error: {_named(str(error))}", file=sys.stderr)
        return _failed(2)
    except KeyboardInterrupt:
        print("mjxcpg: interrupted", file=sys.stderr)
        return _failed(130)
    if result is not None:
        _print_result(result, getattr(args, "json", False))
    return 0


def _named(text: str) -> str:
    """``text``, naming this process when it is one of several and ``text`` does not."""
    processes = sys.modules.get("mjxcpg.jaxutil.processes")
    group = processes.joined() if processes is not None else None
    return text if group is None or text.startswith("process ") else f"process {group.index}: {text}"


def _failed(status: int) -> int:
    """``status``; a process of several ends here and now, not waiting for the others at
    JAX's shutdown (``mjxcpg.jaxutil.processes.exit_now``)."""
    if "mjxcpg.jaxutil.processes" in sys.modules:
        sys.modules["mjxcpg.jaxutil.processes"].exit_now(status)
    return status


def entry(argv: list[str] | None = None) -> int:
    """The ``mjxcpg`` program: ``main`` in a process whose XLA:CPU is set up for this library."""
    from mjxcpg.jaxutil import xla

    xla.one_cpu_thread()
    return main(argv)
