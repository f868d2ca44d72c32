"""The study page (``RESULTS/summary.html``): one file that opens offline.

Every trial with its status; per angle, each trial's range, mean and peak; and, where foot
strikes were found, each trial's mean gait-cycle-normalised curve, one plot per angle.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from kinefuse.lab.report.html_plots import data_uri

#: the mark the study workflow recognizes its own page by (in the first 4 KiB)
MARK = "kinefuse analyze (study)"


def _e(x: object) -> str:
    return html.escape(str(x))


def _num(x: object) -> str:
    return f"{float(x):.1f}" if isinstance(x, int | float | np.floating) else _e(x)


def _cycle_figure(angle: str, method: str, rows: Sequence[dict[str, Any]]) -> Figure:
    fig = Figure(figsize=(5.0, 2.8))
    ax = fig.add_subplot()
    x = np.arange(101)
    for r in rows:
        y = [r[f"p{k}"] for k in range(101)]
        ax.plot(x, y, lw=1.2, label=f"{r['trial']} ({r['cycles']})")
    ax.set_xlabel("gait cycle (%)")
    ax.set_ylabel("degrees")
    ax.set_title(f"{angle} ({method})", fontsize=9)
    ax.grid(alpha=0.3, lw=0.6)
    ax.legend(fontsize=6)
    fig.tight_layout()
    return fig


def render_study(
    result: dict[str, Any], rows: Sequence[dict[str, Any]], cycles: Sequence[dict[str, Any]]
) -> str:
    """The page's HTML."""
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta name="generator" content="{MARK}">',
        f"<title>Study: {_e(result['study'])}</title>",
        "<style>body{font-family:sans-serif;margin:2em;max-width:70em}"
        "table{border-collapse:collapse;font-size:0.85em}"
        "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
        "td:nth-child(-n+3),th:nth-child(-n+3){text-align:left}.failed{color:#b00}</style>",
        "</head><body>",
        f"<h1>Study {_e(result['study'])}</h1>",
        f"<p>Results in <code>{_e(result['out'])}</code>: <code>summary.csv</code>, "
        "<code>cycles.csv</code>, one folder per trial under <code>trials/</code>.</p>",
        "<h2>Trials</h2><table><tr><th>trial</th><th>status</th><th>note</th></tr>",
    ]
    for t in result["trials"]:
        cls = ' class="failed"' if t["status"] == "failed" else ""
        parts.append(
            f"<tr{cls}><td>{_e(t['id'])}</td><td>{_e(t['status'])}</td>"
            f"<td>{_e(t['message'])}</td></tr>"
        )
    parts.append("</table>")
    parts.append(
        "<h2>Angles</h2><p>Per trial and angle, degrees over the frames where it is defined; "
        "peak: the value furthest from zero; cycles: gait cycles found on that side.</p>"
        "<table><tr><th>trial</th><th>angle</th><th>method</th><th>frames</th><th>min</th>"
        "<th>max</th><th>range</th><th>mean</th><th>peak</th><th>cycles</th></tr>"
    )
    for r in rows:
        parts.append(
            f"<tr><td>{_e(r['trial'])}</td><td>{_e(r['angle'])}</td><td>{_e(r['method'])}</td>"
            f"<td>{r['frames']}</td><td>{_num(r['min_deg'])}</td><td>{_num(r['max_deg'])}</td>"
            f"<td>{_num(r['range_deg'])}</td><td>{_num(r['mean_deg'])}</td>"
            f"<td>{_num(r['peak_deg'])}</td><td>{r['cycles']}</td></tr>"
        )
    parts.append("</table>")
    by_angle: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for c in cycles:
        by_angle.setdefault((c["angle"], c["method"]), []).append(c)
    parts.append("<h2>Gait cycles</h2>")
    if not by_angle:
        parts.append("<p>No gait cycle was found in any trial (no walk, or no foot strikes).</p>")
    for (angle, method), group in sorted(by_angle.items()):
        uri = data_uri(_cycle_figure(angle, method, group), dpi=80)
        parts.append(f'<img src="{uri}" alt="{_e(angle)} over the gait cycle">')
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
