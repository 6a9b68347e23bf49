"""The front page and the documentation site say what the code does.

README.md: its Python example runs, every ``tensegrity-sim`` line parses with the real argparse parser, every
extra, executable and launch file it names exists, and its speed table equals what the CSVs hold
(``scripts/readme_table.py --check``). The site: ``mkdocs build --strict`` passes (broken links, missing
references, a macro naming a missing CSV column, any warning fail it). The same CLI check runs over every page.
Benchmark CSVs: ``bench.tables.write_csv`` writes the provenance sidecar the site shows.

The site build needs the ``docs`` extra; without mkdocs that one test skips, unless
``TENSEGRITY_SIM_REQUIRE_DOCS=1`` (CI's no-ROS leg sets it), which makes it fail instead.
"""
import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from bench.tables import markdown_table, provenance, read_csv, write_csv
from tensegrity_sim.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
PAGES = sorted((ROOT / "docs").rglob("*.md"))


def blocks(path: Path, language: str) -> list[str]:
    return [body for lang, body in FENCE.findall(path.read_text()) if lang == language]


def command_lines(path: Path) -> list[str]:
    """The shell lines of a page's bash blocks, comments removed, continuation lines joined."""
    text = "\n".join(blocks(path, "bash")).replace("\\\n", " ")
    return [line.split(" #", 1)[0].strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]


def cli_calls(path: Path) -> list[list[str]]:
    """The argument lists of every ``tensegrity-sim`` call in a page's bash blocks (lines, ``&&``, ``;`` and
    pipes split; comments and what comes before the program, such as VAR=value or /usr/bin/time, dropped) and
    in its code spans (`tensegrity-sim ...` in a sentence)."""
    calls = []
    for block in blocks(path, "bash"):
        lines = [re.sub(r"(^|\s+)#(\s.*)?$", "", line) for line in block.replace("\\\n", " ").splitlines()]
        lexer = shlex.shlex(" ; ".join(lines), posix=True, punctuation_chars="&|;")
        lexer.whitespace_split, lexer.commenters = True, ""
        segment = []
        for token in [*lexer, ";"]:
            if set(token) <= set("&|;"):
                if "tensegrity-sim" in segment:
                    calls.append(segment[segment.index("tensegrity-sim") + 1:])
                segment = []
            else:
                segment.append(token)
    spans = re.findall(r"(?<!`)`tensegrity-sim ([^`]+)`", FENCE.sub("", path.read_text()))
    return calls + [shlex.split(span) for span in spans]


def test_readme_is_a_front_page():
    assert len(README.read_text().splitlines()) <= 150


def test_readme_python_example_runs(tmp_path, monkeypatch):
    """The example runs as written, in a fresh namespace, and simulates what it says (1 s at 1 ms)."""
    (example,) = blocks(README, "python")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(example, "README.md", "exec"), namespace)
    traj = namespace["traj"]
    assert traj.positions.shape == (1000, len(namespace["scene"].nodes), 3)
    assert namespace["sim"].rest_lengths[0] == pytest.approx(0.9)


@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p, "python")], ids=lambda p: str(p.relative_to(ROOT)))
def test_page_python_examples_run(page, tmp_path, monkeypatch):
    """Every Python block of a page runs as written, one namespace per page (blocks build on each other). The
    pages whose examples use JAX (the JAX page, the learning page's functional environment) need the ``jax``
    extra: skipped only where JAX is not installed (CI's ROS leg), unless ``TENSEGRITY_SIM_REQUIRE_JAX=1`` (CI's
    no-ROS leg), which makes a missing JAX fail them."""
    if (page.name in ("jax.md", "learning.md") and os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") != "1"
            and importlib.util.find_spec("jax") is None):
        pytest.skip(f"{page.name}'s examples need the jax extra")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for example in blocks(page, "python"):
        exec(compile(example, str(page), "exec"), namespace)


@pytest.mark.parametrize("page", [README, *PAGES], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_command_line_parses(page):
    """Every ``tensegrity-sim`` call shown parses with the real parser (argparse exits 2 on a bad one)."""
    parser = build_parser()
    for words in cli_calls(page):
        if "--help" in words:
            with pytest.raises(SystemExit) as exit:
                parser.parse_args(words)
            assert exit.value.code == 0
            continue
        args = parser.parse_args(words)
        assert args.verb == words[0]


def test_readme_names_only_what_exists():
    """Extras, executables and launch files that README's commands name are the ones setup.py and launch/ have."""
    setup_text = (ROOT / "setup.py").read_text()
    lines = command_lines(README)
    assert any(line.startswith("tensegrity-sim") or "&& tensegrity-sim" in line for line in lines)
    for extras in re.findall(r'-e "\.\[([\w,]+)\]"', "\n".join(lines)):
        for extra in extras.split(","):
            assert f'"{extra}": [' in setup_text, extra
    for line in lines:
        words = shlex.split(line)
        if words[:2] == ["ros2", "run"]:
            assert words[2] == "tensegrity_sim" and f'"{words[3]} = ' in setup_text
        if words[:2] == ["ros2", "launch"]:
            assert (ROOT / "launch" / words[3]).is_file()


def test_ros_install_steps_are_the_ones_ci_runs():
    """Every pip install of the ROS page asks for extras that one of CI's legs installs together."""
    legs = [set(m.split(",")) for m in re.findall(r"^leg \S+ \S+ ([\w,]+)", (ROOT / ".ci/run").read_text(), re.M)]
    assert any("ros" in leg for leg in legs)
    page = "\n".join(command_lines(ROOT / "docs" / "ros.md"))
    installs = re.findall(r'-e "\.\[([\w,]+)\]"', page)
    assert installs
    for extras in installs:
        assert any(set(extras.split(",")) <= leg for leg in legs), extras
    for step in (".ci/lower_bounds.py", "TENSEGRITY_SIM_REQUIRE_RCLPY=1", "-m pytest -q"):   # the leg's own steps
        assert step in page and step in (ROOT / ".ci/run").read_text(), step


def test_readme_table_matches_the_csvs():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "readme_table.py"), "--check"],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_readme_table_check_fails_on_a_changed_figure(tmp_path, monkeypatch):
    """--check compares figure by figure: one ratio changed in README's table makes it exit 1."""
    spec = importlib.util.spec_from_file_location("readme_table", ROOT / "scripts" / "readme_table.py")
    readme_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(readme_table)
    text = README.read_text()
    ratio = re.search(r"\*\*([0-9.]+)\*\*", text.split(readme_table.BEGIN)[1]).group(1)
    changed = tmp_path / "README.md"
    changed.write_text(text.replace(f"**{ratio}**", f"**{ratio}1**", 1))
    monkeypatch.setattr(readme_table, "README", changed)
    assert readme_table.main(["--check"]) == 1
    assert readme_table.main([]) == 0 and changed.read_text() == text


def test_write_csv_records_provenance(tmp_path, monkeypatch):
    """The sidecar names the command and the commit; the table quotes the numbers and the command."""
    monkeypatch.setattr(sys, "argv", [str(ROOT / "bench" / "bench_x.py"), "--quick"])
    path = tmp_path / "x.csv"
    write_csv(path, [{"scene": "prism3", "us_per_step": 1.23456789}, {"scene": "tower", "us_per_step": 20.0}])
    meta = json.loads(Path(f"{path}.json").read_text())
    assert meta["command"] == "python3 bench/bench_x.py --quick"
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    assert meta["commit"].split()[0] == head.strip() and provenance(path) == meta
    assert read_csv(path)[0]["us_per_step"] == 1.23457
    table = markdown_table(path, columns={"scene": "scene", "us_per_step": "µs"}, where={"scene": "tower"})
    assert table.splitlines()[:3] == ["| scene | µs |", "| --- | --- |", "| tower | 20 |"]
    assert "written by `python3 bench/bench_x.py --quick`" in table
    with pytest.raises(ValueError, match="no column 'steps'"):
        markdown_table(path, columns=["steps"])
    with pytest.raises(ValueError, match="no row matches"):
        markdown_table(path, where={"scene": "icosahedron"})


def test_site_builds_strictly(tmp_path):
    """mkdocs build --strict: any warning (a broken link or anchor, an unknown API name, a macro naming a
    missing CSV, column or row) fails the build."""
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        if os.environ.get("TENSEGRITY_SIM_REQUIRE_DOCS") == "1":
            pytest.fail("TENSEGRITY_SIM_REQUIRE_DOCS=1 but mkdocs or mkdocs-material is not installed (.[docs])")
        pytest.skip("the docs extra is not installed")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                            cwd=ROOT, capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stdout + result.stderr
    assert (tmp_path / "site" / "figures" / "scenes" / "prism3.png").stat().st_size > 10_000
    benchmarks = (tmp_path / "site" / "benchmarks" / "index.html").read_text()
    assert "throughput.csv&quot;" not in benchmarks and "<code>bench/results/throughput.csv</code>" in benchmarks
