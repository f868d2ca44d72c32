"""Fusion of several sensors' joints: the paper's trilateration chain and its baselines.

``trilaterate(joints_sensor, sensor2world, method)`` runs one of :data:`METHODS` on a session;
the ``solve_*`` functions are the batched solvers underneath, on ``(N, K)`` range problems.

May import: errors, io (base), skeleton, geometry, camera, frames, protocol, motion, sync,
occlusion, calibration (the numerical core: no files, sockets or clocks)."""
