"""The live system's networking: the wire protocol's transport, the server, the sensor client,
the fault-injecting proxy, and what the server publishes (publish.py).

The live system's networking: ``address.py`` (``HOST:PORT``, loopback), ``bus.py`` (what the
server publishes and the one interface it publishes through: the contract between the fusion
loop, the recorder, the viewer and any subscriber), ``proxy.py`` (a fault-injecting TCP proxy),
``client/`` (the sensor client), ``server/`` (the live server) and ``lsl.py`` (the Lab
Streaming Layer outlet, a service on the publisher).  Rooms from the bottom: ``net`` itself,
``net.bus``, ``net.proxy``, ``net.client``, ``net.server``, ``net.lsl``; the client and the
server share only ``protocol`` and ``net.bus``, never each other; ``net.lsl`` knows the server
only through ``net.bus``.
"""
