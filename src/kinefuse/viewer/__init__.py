"""The web viewer: a live view of the server's fused skeleton and a replay of recorded sessions.

``live_viewer(publisher)`` serves the live page on the running event loop; ``kinefuse view
SESSION`` serves the replay. The page (``static/``) draws with its own small canvas renderer and
needs nothing beyond this server. Wire format and page in ``docs/viewer.md``.

May import the rooms below it and, of ``net``, only ``net.bus`` (the publisher contract): the
server never imports the viewer.
"""

from kinefuse.viewer.server import DEFAULT_HOST, LiveSource, live_viewer, make_app, serve

__all__ = ["DEFAULT_HOST", "LiveSource", "live_viewer", "make_app", "serve"]
