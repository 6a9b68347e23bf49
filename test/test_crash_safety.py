"""Logs that survive crashes and damage (issue 13): a SIGKILLed run's log is read and recovered, a full
disk stops a run cleanly, replay catches flipped bytes, and every file-system error is one line, exit 2.

The independent readers are mcap's own seeking reader (which needs the summary) and rosbags' rosbag2
reader; neither can open an unfinished log, both must open its recovered copy.
"""
import os
import re
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader as RosbagsReader

from tensegrity_sim import load_scene
from tensegrity_sim import scene as scene_module
from tensegrity_sim.cli import DEFAULT_SCENE, main
from tensegrity_sim.ros.log import CHUNK_SIZE, PENDING_SIZE
from tensegrity_sim.ros.log_reader import LogCorruptError, LogError, LogReader, recover
from tensegrity_sim.ros.replay import log_info, replay

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
RUN = [sys.executable, "-m", "tensegrity_sim.cli", "run", "prism3", "--quiet"]


def independent_counts(path) -> tuple[int, int]:
    """(messages per mcap's seeking reader's statistics, per rosbags)."""
    with open(path, "rb") as f:
        stats = make_reader(f).get_summary().statistics
    with RosbagsReader(path) as bag:
        return stats.message_count, bag.message_count


def test_sigkilled_run_is_read_replayed_and_recovered(tmp_path, capsys):
    path, copy = tmp_path / "killed.mcap", tmp_path / "recovered.mcap"
    proc = subprocess.Popen(RUN + ["--duration", "1000", "--log", str(path)], env=ENV, stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (path.exists() and path.stat().st_size > 3 * CHUNK_SIZE):  # a few chunks written
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    with pytest.raises(Exception):  # what the issue found: an independent reader cannot open it
        independent_counts(path)

    with LogReader(path) as reader:
        n = sum(1 for _ in reader.messages())
        assert reader.unfinished is not None and reader.unfinished.startswith("unfinished log")
        lost = reader.size - reader.offset
    assert n > 100
    assert 0 <= lost < CHUNK_SIZE + PENDING_SIZE  # at most the chunk in progress (and its last message)
    lines = log_info(path)
    assert any(line.startswith("state            unfinished log") for line in lines)
    assert f"messages         {n}" in lines
    report = replay(path)
    assert report.ok and any("unfinished log" in note for note in report.notes), report.lines()
    assert sum(report.compared.values()) == n

    assert main(["recover", str(path), str(copy)]) == 0
    assert capsys.readouterr().out.startswith(f"recovered        {n} messages from {path} (unfinished log")
    assert independent_counts(copy) == (n, n)
    assert replay(copy).ok and not LogReader(copy).unfinished


def test_full_disk_stops_the_run_cleanly_and_keeps_what_was_written(tmp_path):
    """A file-size limit (RLIMIT_FSIZE) fails the log's writes as a full disk does (EFBIG instead of
    ENOSPC): the run stops with one line naming the file and what it keeps, exit 2; the log reads and
    recovers."""
    path = tmp_path / "full.mcap"
    limit = 4 * CHUNK_SIZE + 1000

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    done = subprocess.run(RUN + ["--duration", "1000", "--log", str(path)], env=ENV, capture_output=True, text=True,
                          preexec_fn=limited, timeout=300)
    assert done.returncode == 2
    err = done.stderr.splitlines()
    assert len(err) == 1 and err[0].startswith(f"tensegrity-sim run: error: {path}: writing the log failed at t = ")
    assert err[0].endswith(f"File too large; the file keeps the messages written before the last chunk "
                           f"(tensegrity-sim recover {path} OUT.mcap makes a finished copy)")
    assert path.stat().st_size <= limit
    report = replay(path)
    assert report.ok and sum(report.compared.values()) > 100
    copied, unfinished = recover(path, tmp_path / "copy.mcap")
    assert unfinished and independent_counts(tmp_path / "copy.mcap") == (copied, copied)


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("logs") / "run.mcap"
    assert main(["run", "prism3", "--duration", "0.5", "--quiet", "--log", str(path),
                 "--contacts", "none"]) == 0
    return path


def flipped(src: Path, dst: Path, offset: int) -> Path:
    data = bytearray(src.read_bytes())
    data[offset] ^= 0x01
    dst.write_bytes(bytes(data))
    return dst


def test_flipped_byte_in_a_chunk_is_reported_with_its_position_and_topics(finished_log, tmp_path, capsys):
    with open(finished_log, "rb") as f:
        summary = make_reader(f).get_summary()
    chunk = summary.chunk_indexes[1]
    # the chunk's topics as its index names them (the reader names them from the damaged chunk's index record)
    topics = sorted(summary.channels[c].topic for c in chunk.message_index_offsets)
    assert {"/clock", "/tensegrity_sim/node_poses"} <= set(topics)
    bad = flipped(finished_log, tmp_path / "bad.mcap", chunk.chunk_start_offset + chunk.chunk_length // 2)
    assert main(["replay", str(bad)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == (f"result           CORRUPT LOG: corrupt record at byte {chunk.chunk_start_offset} (messages on "
                       f"{', '.join(topics)}): chunk of t = "
                       f"{chunk.message_start_time * 1e-9:.6f} to {chunk.message_end_time * 1e-9:.6f} s: its CRC "
                       f"does not match")
    assert main(["info", str(bad)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.parametrize("where, message", [
    ("metadata", "while every chunk passes its own: a record outside the chunks (the header, the run info) is damaged"),
    ("summary", "the summary section (indexes, statistics) fails its CRC: other readers may misread the file "
                "(tensegrity-sim recover rewrites it)"),
])
def test_flipped_byte_outside_the_chunks_is_caught_before_anything_is_used(finished_log, tmp_path, where, message):
    data = finished_log.read_bytes()
    offset = data.index(b"scene_yaml") + 40 if where == "metadata" else len(data) - 200
    bad = flipped(finished_log, tmp_path / "bad.mcap", offset)
    with pytest.raises(LogCorruptError, match=re.escape(message)):
        LogReader(bad)
    report = replay(bad)
    assert not report.ok and report.corrupt.endswith(message) and report.steps == 0


def test_every_cut_of_a_log_reads_cleanly(finished_log, tmp_path):
    """A log cut anywhere (as a crash cuts it) is read up to its last complete record: never an exception
    other than LogError, and replay reproduces whatever it holds."""
    data = finished_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    for end in range(8, len(data), len(data) // 23):
        cut.write_bytes(data[:end])
        try:
            report = replay(cut)
        except LogError as exc:  # cut before the run info: not a log yet
            assert "no 'tensegrity_sim' metadata" in str(exc) or "not an MCAP file" in str(exc), str(exc)
            continue
        assert report.ok, (end, report.lines())


# --------------------------------------------------------------------------- file-system errors
FS_ERRORS = [
    (["run", "--log", "/dev/full"], "tensegrity-sim run: error: /dev/full: cannot write the log: No space left on device"),
    (["run", "--log", "{d}/dir.mcap"], "tensegrity-sim run: error: {d}/dir.mcap: cannot write the log: Is a directory"),
    (["run", "--log", "{d}/plain.txt/x.mcap"],
     "tensegrity-sim run: error: {d}/plain.txt/x.mcap: cannot write the log: {d}/plain.txt is not a directory"),
    (["run", "--log", ""], "tensegrity-sim run: error: --log: an empty path (give a .mcap file or a directory)"),
    (["info", "{d}/dir.mcap"], "tensegrity-sim info: error: {d}/dir.mcap: cannot read: Is a directory"),
    (["replay", "{d}/plain.txt/x.mcap"], "tensegrity-sim replay: error: {d}/plain.txt/x.mcap: cannot read: Not a directory"),
    (["recover", "{log}", "/dev/full"], "tensegrity-sim recover: error: /dev/full: cannot write the log: No space left on device"),
    (["recover", "{log}", "{d}/dir.mcap"], "tensegrity-sim recover: error: {d}/dir.mcap: cannot write the log: Is a directory"),
    (["recover", "{log}", "{log}"], "tensegrity-sim recover: error: {log}: the copy must go to another file than the log itself"),
    (["run", "{d}/dir.mcap"], "tensegrity-sim run: error: {d}/dir.mcap: no such scene file, and not a built-in scene "
                              "(built-ins: icosahedron, icosahedron_ground, prism3, superball, three_bar, tower)"),
    (["run", "--commands", "{d}/dir.mcap", "--duration", "0.01"],
     "tensegrity-sim run: error: {d}/dir.mcap: cannot read: Is a directory"),
    # found by scripts/fuzz.py: reading /dev/full as a schedule filled the memory
    (["run", "--commands", "/dev/full", "--duration", "0.01"],
     "tensegrity-sim run: error: /dev/full: not a regular file (a device or a pipe may never end)"),
]


@pytest.mark.parametrize("argv, message", FS_ERRORS, ids=[" ".join(a) for a, _ in FS_ERRORS])
def test_file_system_errors_are_one_line_exit_2(finished_log, tmp_path, capsys, argv, message):
    (tmp_path / "dir.mcap").mkdir()
    (tmp_path / "plain.txt").write_text("x")
    fill = {"d": str(tmp_path), "log": str(finished_log)}
    assert main([a.format(**fill) for a in argv] + (["--duration", "0.01", "--quiet"] if argv[0] == "run" else [])) == 2
    assert capsys.readouterr().err == message.format(**fill) + "\n"


def test_unwritable_log_file_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    """A log file without write permission. Root may write anything, so a root test process takes an
    unprivileged effective user id for the call. That user may not read the checkout, numba's install or
    the package's cached kernels (a clone in a `mktemp -d` folder, a Python under /root): the run's scene
    is a file beside the log (the built-in names listed as this user), and the same run is made first with
    a log it may write, as this user, so that every kernel the run calls is compiled and every module it
    imports loaded; the unprivileged call then opens nothing but the scene and the log."""
    names = scene_module.builtin_scenes()
    monkeypatch.setattr(scene_module, "builtin_scenes", lambda: names)
    folder = tmp_path / "open"
    folder.mkdir()
    scene = folder / "scene.yaml"
    scene.write_text(load_scene(DEFAULT_SCENE).to_yaml())
    scene.chmod(0o444)
    command = ["run", str(scene), "--duration", "0.01", "--quiet", "--log"]
    assert main(command + [str(tmp_path / "warm.mcap")]) == 0
    capsys.readouterr()
    target = folder / "readonly.mcap"
    target.write_bytes(b"")
    target.chmod(0o444)
    root = os.geteuid() == 0
    if root:
        for p in (folder, *folder.parents):
            p.chmod(p.stat().st_mode | 0o001)  # others may pass through to the file (not list, not write)
        os.setegid(65534)
        os.seteuid(65534)
    try:
        status = main(command + [str(target)])
    finally:
        if root:
            os.seteuid(0)
            os.setegid(0)
    assert (status, capsys.readouterr().err) == (
        2, f"tensegrity-sim run: error: {target}: cannot write the log: Permission denied\n")
