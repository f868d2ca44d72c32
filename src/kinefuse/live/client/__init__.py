"""The sensor client: playback of a source, its host clock, the wand and floor in its depth
frames, the connection to the server.

Part of :mod:`kinefuse.live`: shares only ``protocol`` and ``bus`` with the server.
"""
