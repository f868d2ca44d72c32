"""The lab: the only readers of the simulator's truth, and the report.

The evaluation modules compare fusion, calibration, analysis and live runs with the truth
(``*_truth.py``, ``realism*.py``, ``replay_truth.py``) and measure a run where there is no
truth (consistency between sensors, coverage, inspect). ``report/`` renders results (the HTML
report, its figures, the analysis plots) and reads no store and runs no pipeline.

May import every room below it (core, capture, biomech, formats, sim, devices, pipeline);
nothing in live or app is imported, and nothing below reads the truth.
"""
