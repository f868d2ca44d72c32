"""The session store: one SQLite file per capture session, simulated or recorded live: what the
sensors reported (``streams.py``), the live server's extra tables (``live.py``), the simulator's
truth (``truth.py``, read only by :mod:`kinefuse.evaluation`), encodings (``codec.py``).

May import the numerical core below it (frames, camera, calibration, fusion, analysis) and
``io``."""
