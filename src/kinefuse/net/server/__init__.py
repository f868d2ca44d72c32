"""The live server (``kinefuse serve``): connections (``conn.py``), what it keeps per sensor
(``sensor_state.py``), control peers (``control.py``), the 30 Hz fusion loop (``fusion_loop.py``),
the live calibration (``calibration.py``), the recorder (``recorder.py``) and its status
(``report.py``). Threads get snapshots taken on the event loop.

May import everything below it, ``net.bus`` included; never ``net.client`` or ``viewer`` (what
runs beside the server is handed in as a service on its publisher)."""
