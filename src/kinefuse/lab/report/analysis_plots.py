"""Plots of ``kinefuse analyze``: joint angles over time, movement axes on the joint spheres.

Plain arrays in, PNG files out (written through a temporary file and an atomic rename). The
caller picks the matplotlib backend (``kinefuse analyze`` chooses Agg before calling); nothing
here calls ``matplotlib.use``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.outputs import atomic_file, never_replace

Array = NDArray[np.float64]

__all__ = ["angle_groups", "plot_angle_curves", "plot_joint_spheres"]

#: Rows of the angle plot: title -> substrings of the angle names it shows (in order).
_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("trunk / head", ("trunk", "head")),
    ("shoulder", ("shoulder",)),
    ("elbow / forearm", ("elbow", "forearm")),
    ("hip", ("hip",)),
    ("knee", ("knee",)),
    ("ankle", ("ankle",)),
)


def angle_groups(names: Sequence[str]) -> list[tuple[str, list[str]]]:
    """Angle names in the plot's panels: one row per joint, left side then right side (midline
    angles in the left column); names matching no joint go to "other"."""
    left = list(names)
    out = []
    for title, keys in _GROUPS:
        got = [n for n in left if any(n.startswith(k) for k in keys)]
        if not got:
            continue
        left = [n for n in left if n not in got]
        lhs = [n for n in got if not n.endswith("_right")]
        rhs = [n for n in got if n.endswith("_right")]
        out.append((f"{title}" + (" left" if rhs else ""), lhs))
        out.append((f"{title} right", rhs))
    if left:
        out += [("other", left), ("", [])]
    return out


def _save(fig: object, path: Path, *, dpi: int) -> Path:
    import matplotlib.pyplot as plt

    with atomic_file(path, what="plot", recognizer=never_replace, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")  # type: ignore[attr-defined]
    plt.close(fig)  # type: ignore[arg-type]
    return path


def plot_angle_curves(
    path: str | Path,
    t_s: Array,
    angles_deg: Mapping[str, Array],
    *,
    title: str = "",
    truth_deg: Mapping[str, Array] | None = None,
    dpi: int = 80,
) -> Path:
    """Angle curves over time, one panel per joint group (PNG).

    Parameters
    ----------
    path : str or Path
        The PNG to write (must not exist).
    t_s : (T,) float
        Frame times, seconds.
    angles_deg : mapping of str to (T,) float
        Angle name -> degrees (NaN gaps are left blank).
    title : str
        Figure title.
    truth_deg : mapping of str to (T,) float, optional
        The same angles from the true motion, drawn dashed in the same colour.
    dpi : int
    """
    import matplotlib.pyplot as plt

    groups = angle_groups(list(angles_deg))
    n = max(len(groups), 1)
    cols = 2
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(6.5 * cols, 2.3 * rows), sharex=True, squeeze=False
    )
    t = np.asarray(t_s, dtype=np.float64)
    for k, (name, members) in enumerate(groups):
        ax = axes[k // cols][k % cols]
        if not members:
            ax.axis("off")
            continue
        for i, a in enumerate(members):
            colour = f"C{i % 10}"
            ax.plot(t, angles_deg[a], color=colour, lw=1.0, label=a)
            if truth_deg is not None and a in truth_deg:
                ax.plot(t, truth_deg[a], color=colour, lw=0.8, ls="--")
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("deg", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, loc="upper left", ncol=3)
        ax.grid(alpha=0.3)
    for k in range(len(groups), rows * cols):
        axes[k // cols][k % cols].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)", fontsize=8)
    if truth_deg is not None:
        title = (title + "  " if title else "") + "(dashed: from the true motion)"
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, Path(path), dpi=dpi)


def plot_joint_spheres(
    path: str | Path,
    samples: Mapping[str, Array],
    axes_by_limb: Mapping[str, Array],
    *,
    status: Mapping[str, str] | None = None,
    true_axes: Mapping[str, Array] | None = None,
    title: str = "",
    max_points: int = 600,
    dpi: int = 70,
) -> Path:
    """Each limb's movement samples on its joint sphere and its learned axes (PNG).

    Parameters
    ----------
    path : str or Path
        The PNG to write (must not exist).
    samples : mapping of str to (N, 3) float
        Limb -> unit directions of the limb in its parent's normalized frame (points on the
        joint sphere; NaN rows are skipped).
    axes_by_limb : mapping of str to (K, 3) float
        Limb -> its learned rotation axes (unit vectors, same frame), drawn as arrows.
    status : mapping of str to str, optional
        Limb -> status text, shown under the limb's name when not ``"ok"``.
    true_axes : mapping of str to (K, 3) float, optional
        The true axes, drawn dashed.
    title : str
    max_points : int
        At most this many samples per sphere (evenly thinned).
    dpi : int
    """
    import matplotlib.pyplot as plt

    limbs = list(samples)
    n = max(len(limbs), 1)
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig = plt.figure(figsize=(3.0 * cols, 3.0 * rows))
    u, v = np.mgrid[0 : 2 * np.pi : 25j, 0 : np.pi : 13j]
    sphere = (np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v))
    for k, name in enumerate(limbs):
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d")
        ax.plot_wireframe(*sphere, color="0.85", lw=0.3)
        s = np.asarray(samples[name], dtype=np.float64).reshape(-1, 3)
        s = s[np.isfinite(s).all(axis=1)]
        if len(s) > max_points:
            s = s[np.linspace(0, len(s) - 1, max_points).astype(int)]
        if len(s):
            ax.scatter(s[:, 0], s[:, 1], s[:, 2], s=2, c=np.arange(len(s)), cmap="viridis")
        for i, a in enumerate(np.asarray(axes_by_limb.get(name, np.zeros((0, 3)))).reshape(-1, 3)):
            if np.isfinite(a).all():
                ax.quiver(0, 0, 0, *(1.4 * a), color=f"C{3 + i}", lw=2, arrow_length_ratio=0.15)
        if true_axes is not None:
            for a in np.asarray(true_axes.get(name, np.zeros((0, 3)))).reshape(-1, 3):
                if np.isfinite(a).all():
                    ax.plot(*np.stack([np.zeros(3), 1.4 * a]).T, color="k", ls="--", lw=1)
        label = name
        if status is not None and status.get(name, "ok") != "ok":
            label += f"\n{status[name].split(':', 1)[0][:40]}"  # the gist; the report has all
        ax.set_title(label, fontsize=7)
        ax.set_xlim(-1.2, 1.2)
        ax.set_ylim(-1.2, 1.2)
        ax.set_zlim(-1.2, 1.2)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x fwd", fontsize=6, labelpad=-12)
        ax.set_ylabel("y left", fontsize=6, labelpad=-12)
        ax.set_zlabel("z up", fontsize=6, labelpad=-12)
        ax.tick_params(labelsize=0, length=0)
    fig.suptitle(
        (title + "\n" if title else "")
        + "samples: limb direction in the parent's normalized frame; arrows: learned axes"
        + ("; dashed: true axes" if true_axes is not None else ""),
        fontsize=8,
    )
    fig.tight_layout()
    return _save(fig, Path(path), dpi=dpi)
