"""Files: the safe-write rules every writer follows (``outputs.py``: never replace a file kinefuse
did not make; temporary file and atomic rename) and TOML read/write (``toml.py``).

Two rooms below it sit at other heights of the layer table: ``io/store`` (the SQLite session store,
above the numerical core) and ``io/formats`` (readers and writers of file formats, above the
simulator). ``io`` itself may import only errors, so that every layer can write safely."""
