"""``kinefuse maps``: list the shipped sets; ``suggest`` writes a map for a file no set fits
(the rules it can infer, ``TODO`` for the rest); ``check`` refuses it until the TODOs are filled,
then says per joint which rule and markers it uses on how much of the take; the command it
prints next analyses the file. docs/maps.md's commands: tests/test_maps_doc.py."""

from __future__ import annotations

import shlex
import tomllib
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.biomech.marker_maps import shipped_marker_maps
from kinefuse.lab.marker_placement import marker_trial, write_trc

WALK = "motion/cmu/02_walk_a.amc"
#: ISB landmarks under names no shipped set knows: the knees and acromions.
ODD = {"RFLE": "R_KNEE_OUT", "RFME": "R_KNEE_IN", "LFLE": "L_KNEE_OUT", "LFME": "L_KNEE_IN",
       "RSAJ": "R_SHOULDER_TOP", "LSAJ": "L_SHOULDER_TOP"}  # fmt: skip


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_list_shows_every_shipped_set(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "maps", "list")
    assert code == 0
    for name in shipped_marker_maps():
        assert f"  {name} " in out
    assert len(shipped_marker_maps()) >= 8


def test_suggest_then_check_then_analyze(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tr = marker_trial(shared_data / WALK, "isb")
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tuple(ODD.get(n, n) for n in tr.motion_names),
                     tr.motion, up="+z")  # fmt: skip
    out = tmp_path / "my_map.toml"
    code, text, err = run(capsys, "maps", "suggest", str(walk), "--out", str(out))
    assert code == 0, err
    data = tomllib.loads(out.read_text())
    joints = data["joints"]
    todo = {j for j, v in joints.items() if v == "TODO"}
    assert todo == {"KneeLeft", "KneeRight", "ShoulderLeft", "ShoulderRight"}
    assert joints["HipLeft"] == {"hip_joint_centre": "left"}
    assert data["pelvis"]["rasis"] == "RIAS"
    assert joints["ElbowLeft"] == {"mean": ["LHLE", "LHME"]}
    assert "KneeLeft (isb uses LFLE, LFME)" in text
    # the hinted command refuses the map while a TODO is left, naming them
    hint = next(ln for ln in text.splitlines() if ln.startswith("then: "))[len("then: ") :]
    code, _, err = run(capsys, *shlex.split(hint)[1:])
    assert code == 2 and "KneeLeft" in err and "TODO" in err and "Traceback" not in err
    # never replaces a file
    before = out.read_text()
    code, _, err = run(capsys, "maps", "suggest", str(walk), "--out", str(out))
    assert code == 2 and "refusing to replace" in err and out.read_text() == before
    # fill the TODOs with the file's own markers
    filled = (
        before.replace('KneeLeft = "TODO"', 'KneeLeft = { mean = ["L_KNEE_OUT", "L_KNEE_IN"] }')
        .replace('KneeRight = "TODO"', 'KneeRight = { mean = ["R_KNEE_OUT", "R_KNEE_IN"] }')
        .replace('ShoulderLeft = "TODO"', 'ShoulderLeft = "L_SHOULDER_TOP"')
        .replace('ShoulderRight = "TODO"', 'ShoulderRight = "R_SHOULDER_TOP"')
    )
    out.write_text(filled)
    code, text, err = run(capsys, *shlex.split(hint)[1:])
    assert code == 0, err
    rows = {ln.split()[0]: ln for ln in text.splitlines()[1:-1]}
    assert "100.0 % of frames  mean: L_KNEE_OUT, L_KNEE_IN" in rows["KneeLeft"]
    assert "hip joint centre: RIAS, LIAS, RIPS, LIPS" in rows["HipRight"]
    nxt = text.splitlines()[-1]
    assert nxt.startswith("next: kinefuse analyze ")
    argv = shlex.split(nxt[len("next: ") :])[1:]
    argv[argv.index("--out") + 1] = str(tmp_path / "results")
    code, _, err = run(capsys, *argv, "--no-plots")
    assert code == 0, err
    _header, *lines = (tmp_path / "results" / "angles.csv").read_text().splitlines()
    knee = np.array([float(r.split(",")[4]) for r in lines if ",knee_flexion_left," in r])
    assert knee.size > 100 and np.ptp(knee) > 20.0  # a walking knee, from the filled rule


def test_check_names_what_a_map_lacks(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trc = shared_data / "markers/opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc"
    code, text, err = run(capsys, "maps", "check", str(trc), "--map", "rajagopal")
    assert code == 0, err
    assert "KneeLeft" in text and "alternative 3" in text  # the lateral marker alone
    code, _, err = run(capsys, "maps", "check", str(trc), "--map", "plug-in-gait")
    assert code == 2 and "Head: LFHD, RFHD, LBHD, RBHD" in err and "Traceback" not in err
