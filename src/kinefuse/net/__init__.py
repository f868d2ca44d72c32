"""The live system's networking: the wire protocol's transport, the server, the sensor client,
the fault-injecting proxy, and what the server publishes (publish.py)."""
