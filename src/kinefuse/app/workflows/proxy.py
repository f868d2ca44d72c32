"""``kinefuse proxy``: one fault-injecting TCP proxy (:mod:`kinefuse.live.proxy`) as a command."""

from __future__ import annotations


def run_proxy(
    *,
    cut_after_bytes: int | None,
    cut_after_s: float | None,
    down_delay_ms: float,
    down_jitter_ms: float,
    jitter: str,
    listen: tuple[str, int],
    max_cuts: int | None,
    seed: int,
    target: tuple[str, int],
    up_delay_ms: float,
    up_jitter_ms: float,
) -> int:
    """Run one proxy from ``listen`` to ``target`` until Ctrl-C (``kinefuse proxy``'s options)."""
    from kinefuse.live.proxy import LinkProfile, serve_proxy

    host, port = listen
    t_host, t_port = target

    def link(delay_ms: float, jitter_ms: float, cut: int | None) -> LinkProfile:
        return LinkProfile(
            delay_s=delay_ms * 1e-3, jitter_s=jitter_ms * 1e-3, jitter=jitter,
            cut_after_bytes=cut,
        )  # fmt: skip

    return serve_proxy(
        t_host,
        t_port,
        host=host,
        port=port,
        up=link(up_delay_ms, up_jitter_ms, cut_after_bytes),
        down=link(down_delay_ms, down_jitter_ms, None),
        cut_after_s=cut_after_s,
        max_cuts=max_cuts,
        seed=seed,
    )
