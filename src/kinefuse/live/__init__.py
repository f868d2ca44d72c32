"""The live system: the wire protocol, the server, the sensor clients and what runs beside them.

- ``protocol/``: the sans-I/O wire format (messages, codec, handshake and auth; no sockets);
- ``address.py`` (``HOST:PORT``, loopback), ``bus.py`` (what the server publishes and the one
  interface it publishes through), ``proxy.py`` (a fault-injecting TCP proxy);
- ``client/``: the sensor client; ``server/``: the live server; ``lsl.py``: the Lab Streaming
  Layer outlet, a service on the publisher; ``viewer/``: the web viewer (live and replay).

May import every room below it. Inside: the client and the server share only ``protocol`` and
``bus``, never each other; the viewer and the LSL outlet know the server only through ``bus``.
"""
