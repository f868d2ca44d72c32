"""The web viewer: a live view of the server's fused skeleton and a replay of recorded sessions.

``live_viewer(publisher)`` serves the live page on the running event loop; ``kinefuse view
SESSION`` serves the replay. The page (``static/``) needs nothing beyond this server.

Part of :mod:`kinefuse.live`: knows the server only through :mod:`kinefuse.live.bus`.
"""

from kinefuse.live.viewer.http_server import DEFAULT_HOST, LiveSource, live_viewer, make_app, serve

__all__ = ["DEFAULT_HOST", "LiveSource", "live_viewer", "make_app", "serve"]
