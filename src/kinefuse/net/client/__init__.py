"""The sensor client (paper A's client PC): plays one sensor's frames to the server in real time
(``playback.py``: a source spec -> a timeline), answers clock probes on its host clock
(``clocks.py``), detects the wand and fits the floor in its own depth frames (``depth.py``).

May import everything below ``net.client`` (protocol, the core, io, sim, pipeline, net.bus); never
``net.server``."""
