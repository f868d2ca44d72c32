"""``kinefuse proxy``: one fault-injecting TCP proxy."""

from __future__ import annotations

import argparse

from kinefuse.app.cli import args as shared


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse proxy``."""
    from kinefuse.live.proxy import JITTER_KINDS

    p = sub.add_parser(
        "proxy", help="a fault-injecting TCP proxy (delay, jitter, cuts) for testing a live setup"
    )
    p.add_argument(
        "--target",
        required=True,
        type=shared.host_port,
        metavar="HOST:PORT",
        help="where to forward",
    )
    p.add_argument(
        "--listen",
        default=("127.0.0.1", 0),
        type=shared.listen_address,
        metavar="HOST:PORT",
        help="(127.0.0.1:0: a free port)",
    )
    for d, what in (("up", "client -> target"), ("down", "target -> client")):
        p.add_argument(
            f"--{d}-delay-ms", type=shared.nonneg_float, default=0.0, help=f"{what} delay"
        )
        p.add_argument(
            f"--{d}-jitter-ms", type=shared.nonneg_float, default=0.0, help=f"{what} mean jitter"
        )
    p.add_argument(
        "--jitter",
        choices=JITTER_KINDS,
        default="exponential",
        help="distribution of the jitter delays (exponential)",
    )
    p.add_argument("--cut-after-bytes", type=int, help="cut a connection after N bytes up")
    p.add_argument(
        "--cut-after-s", type=shared.nonneg_float, help="cut a connection after S seconds"
    )
    p.add_argument("--max-cuts", type=int, help="cut at most this many connections")
    p.add_argument("--seed", type=int, default=0, help="seed of the jitter draws (0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.proxy import run_proxy

    return run_proxy(
        cut_after_bytes=args.cut_after_bytes,
        cut_after_s=args.cut_after_s,
        down_delay_ms=args.down_delay_ms,
        down_jitter_ms=args.down_jitter_ms,
        jitter=args.jitter,
        listen=args.listen,
        max_cuts=args.max_cuts,
        seed=args.seed,
        target=args.target,
        up_delay_ms=args.up_delay_ms,
        up_jitter_ms=args.up_jitter_ms,
    )
