"""Occlusion detection (client side, 2D bone intersection) and sensor selection (server side).

May import: errors, io (base), skeleton, geometry, camera, frames, protocol, motion, sync."""
