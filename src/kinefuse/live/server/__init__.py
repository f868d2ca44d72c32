"""The live server: connections, per-sensor state, control peers, the 30 Hz fusion loop, the
live calibration, the recorder, its status.

Part of :mod:`kinefuse.live`: never imports the client or the viewer (what runs beside the
server is handed in as a service on its publisher).
"""
