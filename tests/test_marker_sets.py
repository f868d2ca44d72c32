"""Marker sets known by name: each shipped set, under the names different labs and systems give
its markers (subject prefixes, case, separators, side as prefix or suffix, synonyms), placed on
real CMU clips (kinefuse.lab.marker_placement) and read without ``--map``: the set is
chosen by the names and gives back the clip's true joint centres."""

from __future__ import annotations

import json
import re
import shlex
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.app.workflows.analyze import load_input
from kinefuse.formats.markers import marker_key
from kinefuse.lab.marker_placement import marker_trial, write_trc

WALK = "motion/cmu/02_walk_a.amc"
START_STOP = "motion/cmu/131_01_scaled_metres.bvh"

#: Names of the placement without a side letter.
UNSIDED = {"SACR", "SJN", "SXS", "CV7", "TV8", "IJ", "PX", "C7", "T8", "CLAV", "STRN", "T10"}


def _split(n: str) -> tuple[str, str]:
    """(side letter or "", base) of a placement name (Vicon style: ``LKNE``)."""
    if n in UNSIDED or n[0] not in "LR" or "." in n:
        return "", n
    return n[0], n[1:]


def prefixed(subject: str) -> Callable[[str], str]:
    """Vicon Nexus: ``Subject:LASI``."""
    return lambda n: f"{subject}:{n}"


def underscore_prefix(n: str) -> str:
    """Qualisys projects: ``L_IAS``."""
    s, b = _split(n)
    return f"{s}_{b}" if s else n


def suffix(n: str) -> str:
    """Side as a suffix: ``IAS_L``."""
    s, b = _split(n)
    return f"{b}_{s}" if s else n


def glued_lower_suffix(n: str) -> str:
    """Side glued as a lower-case suffix: ``IASl``."""
    s, b = _split(n)
    return f"{b}{s.lower()}" if s else n


def lower_spaced(n: str) -> str:
    """Lower case with a space: ``l ias``."""
    s, b = _split(n)
    return f"{s.lower()} {b.lower()}" if s else n.lower()


def dotted(n: str) -> str:
    """``L.ASIS`` style."""
    s, b = _split(n)
    return f"{s}.{b}" if s else n


#: Helen Hayes / Davis as BTS names it (lower case, spaces; wands "bar 1" / "bar 2") and as
#: Motion Analysis does (R.ASIS, V.Sacral, R.Thigh, R.Shank).
BTS = {"ASI": "asis", "SACR": "sacrum", "THI": "bar 1", "KNE": "knee", "TIB": "bar 2",
       "ANK": "mall", "HEE": "heel", "TOE": "met"}  # fmt: skip
MOTION_ANALYSIS = {"ASI": "ASIS", "SACR": "V.Sacral", "THI": "Thigh", "KNE": "Knee",
                   "TIB": "Shank", "ANK": "Ankle", "HEE": "Heel", "TOE": "Toe"}  # fmt: skip


def bts(n: str) -> str:
    s, b = _split(n)
    return f"{s.lower()} {BTS[b]}" if s else BTS[b]


def motion_analysis(n: str) -> str:
    s, b = _split(n)
    return f"{s}.{MOTION_ANALYSIS[b]}" if s else MOTION_ANALYSIS[b]


#: ISB thorax as several labs name it: STER, XIPH, T1 and T10 (the map's second thorax).
THORAX_2 = {"IJ": "STER", "PX": "XIPH", "C7": "T1", "T8": "T10"}
#: An upper-limb take in Vicon's names (C7 with T10; SHO, LEL/MEL, wrist bar WRA/WRB, FIN).
VICON_UPPER = {"IJ": "CLAV", "PX": "STRN", "T8": "T10", "RAC": "RSHO", "LAC": "LSHO",
               "REL": "RLEL", "LEL": "LLEL", "REM": "RMEL", "LEM": "LMEL", "RRS": "RWRA",
               "LRS": "LWRA", "RUS": "RWRB", "LUS": "LWRB", "RHM2": "RFIN",
               "LHM2": "LFIN"}  # fmt: skip


def same(n: str) -> str:
    return n


#: (set, the map that must read it, naming, up axis, joints checked).
LEGS = ("HipLeft", "HipRight", "KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight")
ARMS = ("ShoulderLeft", "ElbowLeft", "ElbowRight", "WristLeft", "WristRight")
CASES: list[tuple[str, str, Callable[[str], str], str, tuple[str, ...]]] = [
    ("plug-in-gait", "plug-in-gait", prefixed("Patient 1"), "+z", LEGS + ARMS),
    ("helen-hayes", "helen-hayes", same, "+z", LEGS),
    ("helen-hayes", "helen-hayes", bts, "+y", LEGS),
    ("helen-hayes", "helen-hayes", motion_analysis, "+z", LEGS),
    ("isb", "isb", underscore_prefix, "+z", LEGS + ARMS),
    ("isb", "isb", suffix, "+z", LEGS + ARMS),
    ("isb", "isb", glued_lower_suffix, "+z", LEGS + ARMS),
    ("isb", "isb", lower_spaced, "+z", LEGS + ARMS),
    ("upper-limb-isb", "upper-limb-isb", prefixed("Name"), "+z", ARMS),
    ("upper-limb-isb", "upper-limb-isb", lambda n: THORAX_2.get(n, n), "+z", ARMS),
    ("upper-limb-isb", "upper-limb-isb", lambda n: f"Pat:{VICON_UPPER.get(n, n)}", "+z", ARMS),
    ("cast", "cast", same, "+z", LEGS),
    ("cast", "cast", dotted, "+z", LEGS),
    ("rajagopal-run", "rajagopal-run", same, "+y", LEGS + ARMS),
    ("rajagopal", "rajagopal", same, "+y", LEGS + ARMS),
    ("rajagopal", "rajagopal", prefixed("S01"), "+y", LEGS + ARMS),
    ("hamner", "gait2354", same, "+y", LEGS + ARMS),
]


def write_trial(
    tr: object, tmp_path: Path, rename: Callable[[str], str], up: str
) -> tuple[Path, Path]:
    """The static trial and the motion as TRC files under the renamed marker names."""
    static_names = tuple(rename(n) for n in tr.names)  # type: ignore[attr-defined]
    motion_names = tuple(rename(n) for n in tr.motion_names)  # type: ignore[attr-defined]
    assert len(set(static_names)) == len(static_names)
    t_static = np.arange(tr.static.shape[0]) / tr.rate_hz  # type: ignore[attr-defined]
    static = write_trc(tmp_path / "static.trc", t_static, static_names, tr.static, up=up)  # type: ignore[attr-defined]
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, motion_names, tr.motion, up=up)  # type: ignore[attr-defined]
    return walk, static


@pytest.mark.parametrize(
    ("marker_set", "expected", "rename", "up", "joints"),
    CASES,
    ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)],
)
def test_each_set_and_naming_is_read_without_a_map(
    marker_set: str,
    expected: str,
    rename: Callable[[str], str],
    up: str,
    joints: tuple[str, ...],
    shared_data: Path,
    tmp_path: Path,
) -> None:
    tr = marker_trial(shared_data / WALK, marker_set)
    walk, static = write_trial(tr, tmp_path, rename, up)
    inp = load_input(walk, static=static)  # no --map: chosen by the names
    assert f"marker map {expected} " in inp.seq.source, inp.seq.source
    for j in joints:
        err = np.linalg.norm(inp.seq.positions[:, inp.seq.index(j)] - tr.true_joints[j], axis=-1)
        assert np.nanmax(err) < 1e-3, (j, np.nanmax(err))  # metres (TRC: 0.1 um digits)
    assert inp.anatomical is not None and inp.anatomical_status is not None
    leg = "knee_flexion_left" in inp.anatomical
    assert leg == ("KneeLeft" in joints)
    if leg:  # the ISB knee angle of the clip comes back
        d = inp.anatomical["knee_flexion_left"] - tr.true_angles["knee_flexion_left"]
        assert np.sqrt(np.nanmean(d**2)) < 1.0, np.sqrt(np.nanmean(d**2))  # degrees


@pytest.mark.parametrize("marker_set", ["isb", "rajagopal-run", "cast"])
def test_on_a_second_clip(marker_set: str, shared_data: Path, tmp_path: Path) -> None:
    """Start, walk and stop: the sets' joint centres again (another subject and motion)."""
    tr = marker_trial(shared_data / START_STOP, marker_set)
    up = "+y" if marker_set == "rajagopal-run" else "+z"
    walk, static = write_trial(tr, tmp_path, same, up)
    inp = load_input(walk, static=static)
    assert f"marker map {marker_set} " in inp.seq.source
    for j in ("HipRight", "KneeLeft", "AnkleRight"):
        err = np.linalg.norm(inp.seq.positions[:, inp.seq.index(j)] - tr.true_joints[j], axis=-1)
        assert np.nanmax(err) < 1e-3, (j, np.nanmax(err))


@pytest.mark.parametrize(
    "spelling",
    ["LASI", "L_ASIS", "ASIS_L", "L.ASIS", "ASISl", "l asis", "Name:LASI", "L_IAS", "LeftASIS",
     "left asis", "IAS_L"],
)  # fmt: skip
def test_every_spelling_of_a_left_asis_is_one_name(spelling: str) -> None:
    assert marker_key(spelling) == "l:asis"


@pytest.mark.parametrize(
    ("a", "b"),
    [("CLAV", "SJN"), ("SNJ", "IJ"), ("STRN", "SXS"), ("CV7", "C7"), ("TV8", "T8"),
     ("RKNE", "R_FLE"), ("R.Knee.Lat", "RLFC"), ("RANK", "r mall"), ("RHEE", "R_FCC"),
     ("RELB", "R_HLE"), ("RWRA", "R_RSP"), ("RFAulna", "RUSP"), ("RTB1", "RSK1"),
     ("V.Sacral", "SACR"), ("R.PSIS", "RPSI"), ("R_IPS", "RPSI")],
)  # fmt: skip
def test_synonyms_name_one_landmark(a: str, b: str) -> None:
    assert marker_key(a) == marker_key(b)


@pytest.mark.parametrize(
    ("a", "b"), [("LASI", "RASI"), ("RKNE", "RANK"), ("Lumbar", "umbar"), ("LM", "M")]
)
def test_different_landmarks_stay_apart(a: str, b: str) -> None:
    assert marker_key(a) != marker_key(b)


def test_a_file_of_an_unknown_set_gets_at_most_twelve_lines_and_exit_2(
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Markers no shipped set names (and some it does): the closest set, per joint what it
    lacks, and the commands that help, in twelve lines or fewer."""
    tr = marker_trial(shared_data / WALK, "isb")
    renamed = {"RFLE": "R_KNEE_OUT", "RFME": "R_KNEE_IN", "LFLE": "L_KNEE_OUT",
               "LFME": "L_KNEE_IN", "RSAJ": "R_SHOULDER_TOP", "LSAJ": "L_SHOULDER_TOP"}  # fmt: skip
    walk, _ = write_trial(tr, tmp_path, lambda n: renamed.get(n, n), "+z")
    out = tmp_path / "out"
    code = main(["analyze", str(walk), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) <= 12, err
    assert "Closest: 'isb'" in err and "KneeLeft" in err and "LFLE" in err
    assert f"kinefuse maps suggest {walk} --out my_map.toml" in err
    assert not out.exists()
    # the commands it names run as written (from the folder the user is in)
    monkeypatch.chdir(tmp_path)
    suggest = re.search(r"(kinefuse maps suggest .+? --out my_map\.toml)", err)
    check = re.search(r"(kinefuse maps check .+? --map my_map\.toml)", err)
    assert suggest and check, err
    assert main(shlex.split(suggest.group(1))[1:]) == 0
    assert (tmp_path / "my_map.toml").is_file()
    assert main(shlex.split(check.group(1))[1:]) == 2  # its TODOs are not filled yet
    assert "still TODO" in capsys.readouterr().err
    # nothing in common with any shipped set: says so, still short
    (tmp_path / "odd").mkdir()
    numbered = {n: f"M{i:02d}" for i, n in enumerate(tr.names)}
    odd, _ = write_trial(tr, tmp_path / "odd", numbered.__getitem__, "+z")
    assert main(["analyze", str(odd), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "No shipped set shares a marker name" in err and len(err.strip().splitlines()) <= 12


@pytest.mark.parametrize(
    ("marker_set", "rename", "up"),
    [("helen-hayes", bts, "+y"), ("isb", underscore_prefix, "+z")],
    ids=["bts-davis", "qualisys-isb"],
)
def test_analyze_reads_them_without_a_map(
    marker_set: str,
    rename: Callable[[str], str],
    up: str,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The command itself: knee angles written, the set named in the report."""
    tr = marker_trial(shared_data / WALK, marker_set)
    walk, static = write_trial(tr, tmp_path, rename, up)
    out = tmp_path / "out"
    code = main(["analyze", str(walk), "--static", str(static), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 0, err
    report = json.loads((out / "analysis.json").read_text())
    assert f"marker map {marker_set} " in report["source"]
    assert "knee_flexion_left" in report["anatomical"]["angle_names"]


def test_a_cluster_the_file_lacks_leaves_only_its_segment_out(
    shared_data: Path, tmp_path: Path
) -> None:
    """The ISB foot's first metatarsal head under a name no set knows: the map is still chosen
    (every joint builds; the foot from FM2), the feet's anatomical frames are skipped naming
    their cluster, the rest is analysed."""
    tr = marker_trial(shared_data / WALK, "isb")
    renamed = {"LFM1": "L_TOE_BIG", "RFM1": "R_TOE_BIG"}
    walk, static = write_trial(tr, tmp_path, lambda n: renamed.get(n, n), "+z")
    inp = load_input(walk, static=static)
    assert "marker map isb " in inp.seq.source
    status = inp.anatomical_status
    assert status is not None
    assert "RFM1" in status["foot_right"] and status["foot_right"].startswith("skipped")
    assert status["shank_right"] == "ok" and status["thigh_left"] == "ok"
    err = np.linalg.norm(
        inp.seq.positions[:, inp.seq.index("FootLeft")] - tr.true_joints["FootLeft"], axis=-1
    )
    assert np.nanmax(err) < 1e-3
