"""``kinefuse proxy``: one fault-injecting TCP proxy (:mod:`kinefuse.net.proxy`) as a command."""

from __future__ import annotations

import argparse


def _cmd_proxy(args: argparse.Namespace) -> int:
    from kinefuse.net.proxy import LinkProfile, serve_proxy
    from kinefuse.workflows.serve import parse_hostport

    host, port = parse_hostport(args.listen, default_port=0)
    t_host, t_port = parse_hostport(args.target)

    def link(delay_ms: float, jitter_ms: float, cut: int | None) -> LinkProfile:
        return LinkProfile(
            delay_s=delay_ms * 1e-3, jitter_s=jitter_ms * 1e-3, jitter=args.jitter,
            cut_after_bytes=cut,
        )  # fmt: skip

    return serve_proxy(
        t_host,
        t_port,
        host=host,
        port=port,
        up=link(args.up_delay_ms, args.up_jitter_ms, args.cut_after_bytes),
        down=link(args.down_delay_ms, args.down_jitter_ms, None),
        cut_after_s=args.cut_after_s,
        max_cuts=args.max_cuts,
        seed=args.seed,
    )


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``proxy`` to the CLI's subcommands."""
    from kinefuse.cli import _nonneg_float
    from kinefuse.net.proxy import JITTER_KINDS

    p = sub.add_parser(
        "proxy", help="a fault-injecting TCP proxy (delay, jitter, cuts) for testing a live setup"
    )
    p.add_argument("--target", required=True, metavar="HOST:PORT", help="where to forward")
    p.add_argument(
        "--listen", default="127.0.0.1:0", metavar="HOST:PORT", help="(127.0.0.1:0: a free port)"
    )
    for d, what in (("up", "client -> target"), ("down", "target -> client")):
        p.add_argument(f"--{d}-delay-ms", type=_nonneg_float, default=0.0, help=f"{what} delay")
        p.add_argument(
            f"--{d}-jitter-ms", type=_nonneg_float, default=0.0, help=f"{what} mean jitter"
        )
    p.add_argument("--jitter", choices=JITTER_KINDS, default="exponential")
    p.add_argument("--cut-after-bytes", type=int, help="cut a connection after N bytes up")
    p.add_argument("--cut-after-s", type=_nonneg_float, help="cut a connection after S seconds")
    p.add_argument("--max-cuts", type=int, help="cut at most this many connections")
    p.add_argument("--seed", type=int, default=0, help="seed of the jitter draws (0)")
    p.set_defaults(func=_cmd_proxy)
