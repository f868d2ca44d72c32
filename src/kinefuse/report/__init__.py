"""Rendering only: the HTML report, its figures and the analysis plots. Takes results (from
:mod:`kinefuse.evaluation` and the workflows) and writes pages and PNGs.

Reads no store and runs no pipeline: may import the core, ``io`` (safe writes), ``io.formats``
and the result types of ``evaluation``; never ``io.store`` or ``pipeline``."""
