"""The session store: one SQLite file per capture session, simulated or recorded live: what the
sensors reported (``streams.py``), the live server's tables (``live_tables.py``), the
simulator's truth (``truth.py``, read only by :mod:`kinefuse.lab`), encodings (``store_codec.py``).

Part of :mod:`kinefuse.formats`: may import the rooms below it.
"""
