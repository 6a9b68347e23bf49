"""Property-based fuzzing of every public boundary (issue 13): the scene loader (mappings and files), the
Python API, the node's messages, parameters, services and ticks, command schedules, and the command line.

Every case must end accepted (and then be sound: finite state, nothing non-finite published) or refused
with the project's error; a crash is any other exception (see ``fuzz_cases``). CI runs a few thousand
cases with a fixed seed; ``scripts/fuzz.py`` runs the same targets longer, with fresh randomness, and
prints the counts. ``FUZZ_SCALE`` multiplies every target's number of cases.
"""
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzz_cases as F

SCALE = float(os.environ.get("FUZZ_SCALE", "1"))
RANDOM = os.environ.get("FUZZ_RANDOM") == "1"  # scripts/fuzz.py: fresh cases each run


def cases(n: int):
    return settings(max_examples=max(1, int(n * SCALE)), deadline=None, derandomize=not RANDOM, database=None,
                    suppress_health_check=list(HealthCheck))


@cases(1200)
@given(F.scene_dicts())
def test_scene_dicts(mapping):
    F.fuzz_scene_dict(mapping)


@cases(150)
@given(F.VALUES)
def test_scene_dicts_of_anything(value):
    F.fuzz_scene_dict(value)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@cases(500)
@given(F.scene_texts())
def test_scene_files(fuzz_dir, text):
    F.fuzz_scene_file(fuzz_dir, text)


@cases(400)
@given(st.integers(0, 9).flatmap(lambda i: st.sampled_from([1e-3, 2e-4]) if i < 8  # mostly a valid dt
                                 else st.one_of(F.FLOATS, F.INTS, F.TEXT)),
       st.sampled_from(["auto", "elastic", "inextensible"]), F.API_CALLS)
def test_api(dt, method, calls):
    F.fuzz_api(dt, method, calls)


@cases(300)
@given(st.dictionaries(st.sampled_from(["dt", "step_rate", "publish_rate", "marker_rate", "real_time_factor",
                                        "max_rest_length_rate"]),
                       st.one_of(st.sampled_from([1e-3, 1e-6, 1e6, 1e300, 5e-324, 0.0, 100.0]), F.FLOATS),
                       max_size=2),
       F.NODE_ACTIONS)
def test_node(settings_changes, actions):
    F.fuzz_node(settings_changes, actions)


@cases(500)
@given(F.COMMAND_POINTS)
def test_command_schedules(points):
    F.fuzz_commands(points)


@pytest.fixture(scope="module")
def cli_dir(tmp_path_factory):
    """Files the command-line cases name: a valid log, a bad scene, a plain file, a directory named
    ``*.mcap``."""
    from tensegrity_sim.cli import main

    d = tmp_path_factory.mktemp("cli")
    (d / "bad.yaml").write_text("nodes: [{name: a\n")
    (d / "plain.txt").write_text("not a log\n")
    (d / "dir.mcap").mkdir()
    assert main(["run", "prism3", "--duration", "0.01", "--quiet", "--log", str(d / "log.mcap")]) == 0
    return d


@cases(250)
@given(st.data())
def test_command_line(cli_dir, monkeypatch, data):
    monkeypatch.chdir(cli_dir)  # a log spec that is a plain word makes a directory here
    F.fuzz_cli(data.draw(F.cli_argv(cli_dir)))

