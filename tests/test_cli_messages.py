"""Every message a user sees names command-line flags and files, not the Python API (issue 8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.capture.calibration.register import Sightings, register_full
from kinefuse.errors import CalibrationError, RigError
from kinefuse.sim.rig import load_rig


@pytest.mark.parametrize("command", ["realdata"])
def test_report_commands_show_their_own_usage(command, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: kinefuse {command}")
    assert "python -m" not in out and "kinefuse-" not in out


def test_duplicate_sensor_ids_name_the_rig_file(tmp_path) -> None:
    rig = tmp_path / "dup.toml"
    one = '[[sensor]]\nid = "a"\nposition_m = [3.0, 0.0, 1.0]\nlook_at_m = [0, 0, 1]\n'
    rig.write_text(one + one.replace("3.0", "-3.0"))
    with pytest.raises(RigError, match=rf"{rig}: sensor ids must be unique; repeated: a"):
        load_rig(rig)


def test_too_few_sensors_for_calibration_is_said_plainly() -> None:
    s = Sightings(np.arange(3.0), np.ones((3, 3)), np.ones(3))
    with pytest.raises(CalibrationError) as e:
        register_full({"k0": s})
    msg = str(e.value)
    assert "register_full" not in msg and "at least 2 sensors that saw the wand" in msg


def test_simulate_names_the_name_map_flag(tmp_path, capsys) -> None:
    clip = tmp_path / "odd.bvh"
    clip.write_text(
        "HIERARCHY\nROOT Blob\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n"
        "  JOINT Tail\n  {\n    OFFSET 0 10 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "    End Site\n    {\n      OFFSET 0 10 0\n    }\n  }\n}\nMOTION\nFrames: 2\n"
        "Frame Time: 0.0333\n0 0 0 0 0 0\n0 0 0 0 0 0\n"
    )
    code = main(["simulate", "--clip", str(clip), "--out", str(tmp_path / "s.sqlite")])
    err = capsys.readouterr().err
    assert code == 2 and "--name-map" in err and "name_map=" not in err
    assert not (tmp_path / "s.sqlite").exists()


def test_oserrors_become_one_line_errors(tmp_path, capsys) -> None:
    missing: Path = tmp_path / "nope.amc"
    code = main(["simulate", "--clip", str(missing), "--out", str(tmp_path / "s.sqlite")])
    err = capsys.readouterr().err.splitlines()[-1]
    assert code == 2 and err.startswith("kinefuse: error:") and "nope.amc" in err


def test_an_unreadable_input_is_one_line(tmp_path, capsys) -> None:
    folder = tmp_path / "clip.bvh"
    folder.mkdir()  # reading a folder as a file: an OSError, not a traceback
    code = main(["inspect", str(folder)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(folder) in err
