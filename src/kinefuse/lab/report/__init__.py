"""Rendering only: the HTML report, its figures and the analysis plots. Takes results (from
:mod:`kinefuse.lab` and the workflows) and writes pages and PNGs.

Part of :mod:`kinefuse.lab`: reads no store and runs no pipeline (never
:mod:`kinefuse.formats.store` or :mod:`kinefuse.pipeline`).
"""
