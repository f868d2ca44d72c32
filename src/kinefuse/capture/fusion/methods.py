"""The fusion methods by name: one tuple per list, imported by the modules that implement them
and by the command line (this module imports nothing, so building the parser stays light)."""

#: The trilateration solvers (paper A's comparison): fusion.trilateration.trilaterate.
TRILATERATION_METHODS: tuple[str, ...] = ("linear", "geometric", "nonlinear", "paper")
#: Every method a session can be fused with (:func:`kinefuse.capture.fusion.fusion_run.run_method`).
METHODS: tuple[str, ...] = (*TRILATERATION_METHODS, "best", "best-live")
#: The methods the live server runs frame by frame (:mod:`kinefuse.live.server.fusion_loop`).
LIVE_METHODS: tuple[str, ...] = ("best-live", "paper")
