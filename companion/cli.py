"""`m4-companion`: the companion's command line.

Each subcommand is one `_add_<name>(subparsers)` function that declares its arguments and
sets `func` (called with the parsed arguments, returns the exit code), registered under its
name by one line in SUBCOMMANDS. A command line that names one builds that parser alone: the
others import their modules (the dashboard's loads pymavlink's tlog reader and its dialects),
a cost at every `run` a flight starts.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from m4.arguments import positive_int, positive_number


def _add_bench(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="time warm-started NMPC solves beside IPOPT on the same problems")
    p.add_argument("--horizon", type=positive_int, default=5, help="NMPC horizon N (default 5)")
    p.add_argument("--dt", type=positive_number, default=0.1, help="NMPC step in seconds (default 0.1)")
    p.add_argument("--period", type=positive_number, default=None,
                   help="control period in seconds, one solve each (default: the NMPC step)")
    p.add_argument("--solves", type=positive_int, default=300, help="solves in the sequence (default 300)")
    p.add_argument("--seed", type=int, default=0, help="seed of the kicks and noise")
    p.add_argument("--json", action="store_true", help="print one JSON object on one line")
    p.set_defaults(func=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    # CasADi, the solver and the research code load only when needed
    from companion.config import CompanionConfig
    from companion.core.nmpc import Nmpc
    from companion.headroom import control_step_ms, headroom_lines, summary
    from research.nmpc_bench import bench_sequence, run_bench

    report = run_bench(horizon=args.horizon, dt_s=args.dt, solves=args.solves, seed=args.seed,
                       control_period_s=args.period)
    config = CompanionConfig()                   # the whole control step, at the default rate
    states = bench_sequence(config.airframe, Nmpc(config.airframe, config.nmpc), args.solves, args.seed)
    step_ms = control_step_ms(config, states.x_measured, states.thrust_max_known_n)
    if args.json:
        print(json.dumps({**report.as_dict(), **summary(step_ms)}))
    else:
        print("\n".join([report.table(), *headroom_lines(step_ms)]))
    return 0


def _add_watch(sub: argparse._SubParsersAction) -> None:
    from companion import watch

    p = sub.add_parser("watch", help="show the companion's live Zenoh feed in a terminal")
    watch.add_arguments(p)
    p.set_defaults(func=watch.run)


def _add_dashboard(sub: argparse._SubParsersAction) -> None:
    from companion.dashboard import command

    p = sub.add_parser("dashboard", help="serve a web dashboard of the live Zenoh feed, or replay a recorded flight")
    command.add_arguments(p)
    p.set_defaults(func=command.run)


def _add_run(sub: argparse._SubParsersAction) -> None:
    from companion import run

    p = sub.add_parser("run", help="fly: MAVLink telemetry in, NMPC setpoints out, at the control rate")
    run.add_arguments(p)
    p.set_defaults(func=run.run)


def _add_keygen(sub: argparse._SubParsersAction) -> None:
    from companion import keygen

    p = sub.add_parser("keygen", help="make a MAVLink signing key file for the companion and its flight controller")
    keygen.add_arguments(p)
    p.set_defaults(func=keygen.run)


def _add_plot(sub: argparse._SubParsersAction) -> None:
    from companion import plot

    p = sub.add_parser("plot", help="figures and metrics of a flight from its tlog (the plot extra)")
    plot.add_arguments(p)
    p.set_defaults(func=plot.run)


# One line per subcommand.
SUBCOMMANDS = {
    "bench": _add_bench,
    "watch": _add_watch,
    "dashboard": _add_dashboard,
    "run": _add_run,
    "keygen": _add_keygen,
    "plot": _add_plot,
}


def single_thread_blas() -> None:
    """The control loop's matrices are small: BLAS worker threads only contend with it on a
    2-core computer (they gave 10x tails at N = 20). Takes effect before numpy loads."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv: list[str] | None = None) -> int:
    single_thread_blas()
    parser = argparse.ArgumentParser(prog="m4-companion", description="M4 companion: NMPC fault recovery")
    sub = parser.add_subparsers(dest="command", required=True)
    named = sys.argv[1:2] if argv is None else argv[:1]
    for add in [SUBCOMMANDS[named[0]]] if named and named[0] in SUBCOMMANDS else SUBCOMMANDS.values():
        add(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
