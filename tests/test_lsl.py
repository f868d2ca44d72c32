"""The LSL outlet (``kinefuse serve --lsl``, docs/lsl.md) on the REAL system, confined to loopback.

As ../shared/design/LSL.md says: the live run (``tests/lsl_loopback_run.py``: ``kinefuse serve``
with real ``kinefuse sensor`` processes and a discovery-free inlet) runs inside ``unshare -rn``
with only ``lo`` up, under ``strace -f``; the test fails on any connect/sendto/sendmsg to an
address outside 127.0.0.0/8 and on any multicast join. The bad-input tests need no LSL traffic.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.live.lsl import CHANNELS, channel_labels, check_stream_name

RUN = Path(__file__).resolve().parent / "lsl_loopback_run.py"
TRACE = "trace=connect,sendto,sendmsg,setsockopt"
_V4 = re.compile(r'inet_addr\("([^"]*)"\)')
_V6 = re.compile(r'inet_pton\(AF_INET6, "([^"]*)"')
_JOIN = re.compile(r"IP_ADD_MEMBERSHIP|IPV6_ADD_MEMBERSHIP|IPV6_JOIN_GROUP|MCAST_JOIN")


def outside_loopback(trace: str) -> list[str]:
    """The strace lines that send to or connect to an address outside 127.0.0.0/8 (or ::1), or
    join a multicast group."""
    bad = []
    for line in trace.splitlines():
        if _JOIN.search(line):
            bad.append(line)
            continue
        if not re.search(r"\b(connect|sendto|sendmsg)\(", line):
            continue
        v4 = [a for a in _V4.findall(line) if not a.startswith("127.")]
        v6 = [a for a in _V6.findall(line) if a != "::1" and not a.startswith("::ffff:127.")]
        if v4 or v6:
            bad.append(line)
    return bad


def test_the_trace_check_can_fail() -> None:
    ok = [
        '12 connect(7, {sa_family=AF_INET, sin_port=htons(26572), sin_addr=inet_addr("127.0.0.1")'
        "}, 16) = 0",
        '12 sendto(9, "x", 1, 0, {sa_family=AF_INET, sin_port=htons(16571), '
        'sin_addr=inet_addr("127.0.0.1")}, 16) = 1',
        '12 connect(3, {sa_family=AF_UNIX, sun_path="/run/x"}, 110) = -1 ENOENT',
    ]
    assert outside_loopback("\n".join(ok)) == []
    for line in [
        '12 sendto(9, "x", 1, 0, {sa_family=AF_INET, sin_port=htons(16571), '
        'sin_addr=inet_addr("239.255.172.215")}, 16) = 1',
        '12 connect(7, {sa_family=AF_INET, sin_port=htons(80), sin_addr=inet_addr("10.0.0.2")}, '
        "16) = -1 ENETUNREACH",
        '12 sendmsg(7, {msg_name={sa_family=AF_INET, sin_port=htons(16571), sin_addr=inet_addr("2'
        '55.255.255.255")}, msg_namelen=16}, 0) = 1',
        '12 setsockopt(8, SOL_IP, IP_ADD_MEMBERSHIP, {imr_multiaddr=inet_addr("224.0.0.183")}, '
        "8) = 0",
        "12 connect(7, {sa_family=AF_INET6, sin6_port=htons(1), sin6_addr=inet_pton(AF_INET6, "
        '"ff02::113")}, 28) = 0',
    ]:
        assert outside_loopback("\n".join([*ok, line])) == [line]


def test_channel_labels() -> None:
    labels = channel_labels()
    assert len(labels) == CHANNELS == 100
    assert labels[:4] == ["SpineBase_X", "SpineBase_Y", "SpineBase_Z", "SpineMid_X"]
    assert labels[75] == "SpineBase_Status" and labels[-1] == f"{JOINTS[-1]}_Status"


@pytest.mark.parametrize(
    ("name", "says"),
    [
        ("", "empty"),
        ("x" * 65, "at most 64"),
        ("kine\x00fuse", "'\\x00'"),
        ("kine\nfuse", "'\\n'"),
        ("<stream>", "'<'"),
        (" lab", "blank"),
    ],
)
def test_odd_stream_names_are_refused(name: str, says: str) -> None:
    with pytest.raises(InputError, match=re.escape(says)):
        check_stream_name(name)
    assert check_stream_name("kinefuse lab 2 (VR)") == "kinefuse lab 2 (VR)"


def _serve(*args: str, pre: str = "") -> subprocess.CompletedProcess[str]:
    code = f"{pre}import sys; from kinefuse.app.cli.main import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", code, "serve", "--port", "0", *args],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def test_serve_refuses_an_odd_name_and_a_missing_pylsl_before_listening() -> None:
    run = _serve("--lsl", "bad\x01name")
    assert run.returncode == 2, run.stderr
    assert "stream name" in run.stderr and "listening" not in run.stdout
    # pylsl not installed (import blocked as Python does for a missing module)
    run = _serve(
        "--lsl", pre="sys_modules = __import__('sys').modules; sys_modules['pylsl'] = None; "
    )
    assert run.returncode == 2, run.stderr
    assert "kinefuse[lsl]" in run.stderr and "listening" not in run.stdout
    run = _serve("--lsl-xml", "x.xml")
    assert run.returncode == 2 and "give --lsl too" in run.stderr


def _namespace_problem() -> str | None:
    """Why the loopback-only run cannot happen here (None: it can)."""
    for tool in ("unshare", "strace", "ip"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (.ci/run installs util-linux, strace and iproute2)"
    probe = subprocess.run(
        ["unshare", "-rn", "sh", "-c", "ip link set lo up"], capture_output=True, text=True
    )
    if probe.returncode != 0:
        return f"unshare -rn is not permitted here: {probe.stderr.strip()}"
    return None


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate

    out = tmp_path_factory.mktemp("lsl") / "sim.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=3, seconds=20.0, calibration_s=9.0)
    return out


@pytest.mark.slow
def test_lsl_stream_of_a_live_run_stays_on_loopback(tmp_path: Path, session: Path) -> None:
    pytest.importorskip("pylsl")
    why = _namespace_problem()
    if why is not None:
        pytest.skip(why)
    trace, out = tmp_path / "strace.log", tmp_path / "result.json"
    work = tmp_path / "work"
    work.mkdir()
    cmd = [
        "unshare", "-rn", "sh", "-c", 'ip link set lo up && exec "$@"', "sh",
        "strace", "-f", "-qq", "--seccomp-bpf", "-e", TRACE, "-o", str(trace),
        sys.executable, str(RUN), "--session", str(session), "--work", str(work),
        "--out", str(out),
    ]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    r = json.loads(out.read_text())
    print(json.dumps({k: v for k, v in r.items() if k != "channels"}, indent=1))  # the figures
    assert r["interfaces"] == ["lo"]
    assert r["config_loaded"] and r["server_config_loaded"]
    # no packet left loopback, no multicast group joined (and the trace saw the LSL traffic)
    log = trace.read_text(errors="replace")
    assert outside_loopback(log) == []
    assert re.search(r'connect\(.*inet_addr\("127\.0\.0\.1"\)', log)
    # the stream as documented
    s = r["stream"]
    assert (s["type"], s["channel_count"], s["nominal_srate"]) == ("MoCap", 100, 30.0)
    assert s["channel_format"] == r["cf_float32"] and "z up" in s["reference_frame"]
    assert [c["label"] for c in r["channels"]] == channel_labels()
    assert {(c["type"], c["unit"]) for c in r["channels"][:75]} == {("Position", "meters")}
    assert {c["type"] for c in r["channels"][75:]} == {"Status"}
    # >= 99 % of the fused frames, each sample equal to its recorded frame
    assert r["server_rc"] == 0 and r["sensor_rcs"] == [0, 0, 0]
    n = r["fused_frames_recorded"]
    assert n == r["fused_frames_said"] and n > 15 * 30  # frames are fused once calibrated
    assert r["samples_not_matching_their_frame"] == 0
    assert r["frames_matched"] >= 0.99 * n, (r["frames_matched"], n)
    assert r["samples_with_positions"] > 10 * 30
    # time stamps: mapped back, the server clock within 1 ms; the map is the server's own t0
    assert r["max_abs_time_error_s"] < 1e-3
    assert abs(r["offset_minus_server_t0_monotonic_s"]) < 1e-3
    assert abs(r["monotonic_minus_local_clock_s"]) < 1e-3


PEOPLE_RUN = Path(__file__).resolve().parent / "lsl_people_run.py"


@pytest.fixture(scope="module")
def crowd(tmp_path_factory: pytest.TempPathFactory, shared_data: Path) -> Path:
    """4 sensors, 5 s of the subject with one bystander walking between them and a sensor."""
    from kinefuse.app.workflows.simulate import run_simulate

    out = tmp_path_factory.mktemp("lsl_people") / "crowd.sqlite"
    cmu = shared_data / "motion" / "cmu"
    run_simulate(clip=cmu / "01_01.amc", out=out, seconds=5.0, calibration_s=1.0,
                 depth_rate_hz=5.0, seed=2, bystanders=(cmu / "02_walk_a.amc",))  # fmt: skip
    return out


@pytest.mark.slow
def test_lsl_people_all_gives_one_stream_per_person_on_loopback(
    tmp_path: Path, crowd: Path
) -> None:
    """``serve --lsl --people all``: the subject's stream as before and one stream per person,
    named by id, each sample the person's fused frame, nothing leaving loopback."""
    pytest.importorskip("pylsl")
    why = _namespace_problem()
    if why is not None:
        pytest.skip(why)
    trace, out = tmp_path / "strace.log", tmp_path / "result.json"
    work = tmp_path / "work"
    work.mkdir()
    cmd = [
        "unshare", "-rn", "sh", "-c", 'ip link set lo up && exec "$@"', "sh",
        "strace", "-f", "-qq", "--seccomp-bpf", "-e", TRACE, "-o", str(trace),
        sys.executable, str(PEOPLE_RUN), "--session", str(crowd), "--work", str(work),
        "--out", str(out),
    ]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    r = json.loads(out.read_text())
    print(json.dumps(r, indent=1))  # the figures
    assert outside_loopback(trace.read_text(errors="replace")) == []
    assert r["config_loaded"] and r["sensor_rcs"] == [0, 0, 0, 0]
    name = "kinefuse-people-test"
    assert r["outlets"] == [name, f"{name}_p0", f"{name}_p1"]
    assert r["frames_with_two_people"] > 60
    s = r["streams"]
    assert [s[k]["name"] for k in ("subject", "p0", "p1")] == r["outlets"]
    for k in ("subject", "p0", "p1"):
        # every sample is its person's fused frame, bit for bit (float32), at its frame's time
        assert s[k]["not_matching"] == 0 and s[k]["not_a_frame"] == 0, (k, s[k])
        assert s[k]["with_positions"] > 60, (k, s[k])


def test_serve_refuses_people_all_without_lsl_and_a_name_too_long_for_it() -> None:
    run = _serve("--people", "all")
    assert run.returncode == 2 and "give --lsl too" in run.stderr, run.stderr
    run = _serve("--lsl", "x" * 60, "--people", "all")
    assert run.returncode == 2 and "at most 59 characters" in run.stderr, run.stderr
