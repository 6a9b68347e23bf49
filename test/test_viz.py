"""Looking at a run: a log read back as arrays (against the run itself), its figures, the sweep figure,
and the 3-D page (its frames against the log; in a real browser when one is installed)."""
import re
import shutil
import subprocess
from dataclasses import replace
from importlib import resources

import matplotlib.image
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tensegrity_sim as ts
from tensegrity_sim.cli import main, simulate
from tensegrity_sim.commands import load_commands
from tensegrity_sim.ros.offline import logged_run
from tensegrity_sim.ros.record import read_log, with_energy
from tensegrity_sim.viz.page import build_figure, frame_indices
from tensegrity_sim.results import ContactEvent
from tensegrity_sim.viz.plots import _spans, plot_contacts, shown_cables

DURATION = 3.2  # s: the demo's side cables reeled out (all slack) and back in (all snap) by then


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The main job's run, 3.2 s, logged; with what the simulator said at every step."""
    path = tmp_path_factory.mktemp("demo") / "demo.mcap"
    sim = ts.Simulator(ts.load_scene("prism3"))
    with resources.as_file(resources.files("tensegrity_sim.schedules") / "prism3_demo.yaml") as schedule:
        commands = load_commands(schedule, sim.scene)
    steps = []
    with logged_run(sim, str(path)) as driver:
        simulate(sim, int(round(DURATION / sim.dt)), commands, driver=driver,
                 on_step=lambda r: steps.append((r, sim.energy())))
    return path, steps


def test_read_log_holds_the_run_at_every_publication(demo):
    path, steps = demo
    record = read_log(path)
    every = 10  # publish_rate 100 Hz, dt 1 ms
    assert len(record.times) == len(steps) // every
    for k, t in enumerate(record.times):
        r = steps[(k + 1) * every - 1][0]
        assert t == pytest.approx(r.time, abs=1e-12)
        # CDR float64: bit for bit
        assert np.array_equal(record.positions[k], r.positions)
        assert np.array_equal(record.tensions[k], r.tensions)
        assert np.array_equal(record.slack[k], r.slack)  # elastic: slack exactly when the tension is 0
        interval = [s.impulses for s, _ in steps[k * every:(k + 1) * every]]
        np.testing.assert_allclose(record.impulses[k], np.sum(interval, axis=0), rtol=1e-12, atol=0)
    # the schedule: all nine cables slack after the reel-out, all taut again after the reel-in
    assert record.slack[record.times.searchsorted(2.5)].all()
    assert not record.slack[-1].any()
    k, c = record.snaps
    assert sorted(c[(record.times[k] > 3.0) & (record.times[k] < 3.2)].tolist()) == list(range(9))


def test_energy_is_the_run_s_own(demo):
    path, steps = demo
    record = with_energy(read_log(path))
    assert record.energy_note == ""
    for k in range(len(record.times)):
        expected = steps[(k + 1) * 10 - 1][1]
        assert {name: v[k] for name, v in record.energy.items()} == expected


def test_spans_of_a_mask():
    assert _spans(np.array([0, 1, 1, 0, 1], bool)) == [(1, 2), (4, 4)]
    assert _spans(np.zeros(3, bool)) == []


def test_plot_writes_png_and_svg_titled_by_scene_method_dt(demo, tmp_path):
    path, _ = demo
    assert main(["plot", str(path), "--out", str(tmp_path / "figs")]) == 0
    for name in ("tensions", "impulses", "energy", "contacts"):
        image = matplotlib.image.imread(tmp_path / "figs" / f"{name}.png")
        assert image.shape[0] > 150 and image[..., :3].std() > 0.05  # not blank
        svg = (tmp_path / "figs" / f"{name}.svg").read_text()
        assert "prism3 - elastic, dt = 0.001 s" in svg
    assert "snap" in (tmp_path / "figs" / "tensions.svg").read_text()
    assert "no contact" in (tmp_path / "figs" / "contacts.svg").read_text()


def test_plot_and_view_refuse_what_is_not_a_log(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.mcap").write_text("not a log")
    assert main(["plot", str(tmp_path / "notes.mcap")]) == 2
    assert main(["view", str(tmp_path / "missing.mcap")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"tensegrity-sim plot: error: {tmp_path / 'notes.mcap'}: not an MCAP file (it does not start with the MCAP magic)")
    assert err[1].startswith(f"tensegrity-sim view: error: {tmp_path / 'missing.mcap'}: cannot read")
    assert not (tmp_path / "plots").exists()  # nothing written


def test_plot_of_a_sweep_table_leaves_failed_runs_out(tmp_path, capsys):
    """Column names as the sweep writes them: the varied keys as in its spec, then the results."""
    table = pa.table({"rest_lengths.c0": [0.62, 0.64, 0.66, 0.68], "dt": [1e-3] * 4,
                      "max_tension": [80.0, 61.0, 44.0, 0.0], "snaps": [0, 2, 5, 1],
                      "failed": [None, None, None, "QPError: status -1"]})
    pq.write_table(table, tmp_path / "sweep.parquet")
    assert main(["plot", str(tmp_path / "sweep.parquet"), "--x", "rest_lengths.c0", "--out", str(tmp_path)]) == 0
    svg = (tmp_path / "sweep.svg").read_text()
    assert "max_tension against rest_lengths.c0 (3 runs, 1 failed and left out)" in svg
    assert main(["plot", str(tmp_path / "sweep.parquet"), "--x", "mass.n0"]) == 2
    assert "x column 'mass.n0' is not in the table" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "sweep.parquet"), "--y", "failed"]) == 2
    assert "y column 'failed' is not numeric" in capsys.readouterr().err


def test_frames_are_subsampled_within_both_budgets(demo):
    record = read_log(demo[0])  # 320 publications; prism3: 3 struts, 9 cables -> 135 values a frame
    assert frame_indices(record, max_frames=400).tolist() == list(range(320))
    picked = frame_indices(record, max_frames=100)
    assert picked.tolist() == list(range(0, 320, 4)) + [319]
    assert frame_indices(record, max_values=135 * 40).tolist() == list(range(0, 320, 9)) + [319]  # 37 <= 40


def test_page_frames_show_the_logged_structure(demo):
    record = read_log(demo[0])
    picked = frame_indices(record, max_frames=50)
    fig = build_figure(record, picked)
    assert len(fig.frames) == len(picked)
    ends = record.system
    for frame, k in zip(fig.frames, picked):
        struts, taut, slack, contacts = frame.data
        pts = np.column_stack([struts.x, struts.y, struts.z]).reshape(-1, 3, 3)
        np.testing.assert_array_equal(pts[:, :2], record.positions[k][ends.strut_ends].astype(np.float32))
        assert np.isnan(pts[:, 2]).all()  # the gap after each segment
        assert len(slack.x) == 3 * record.slack[k].sum() and len(taut.x) == 3 * (~record.slack[k]).sum()
        np.testing.assert_array_equal(taut.line.color[::3], record.tensions[k][~record.slack[k]].astype(np.float32))
        assert len(contacts.x) == 0
    assert fig.data[2].line.dash == "dash"
    steps = fig.layout.sliders[0].steps
    assert [s.args[0][0] for s in steps] == [f.name for f in fig.frames]


@pytest.fixture(scope="module")
def page(demo):
    """The page of the demo run, as ``view`` writes it."""
    path = demo[0].with_suffix(".html")
    assert main(["view", str(demo[0]), "--out", str(path)]) == 0
    return path


def test_page_is_self_contained(page):
    html = page.read_text()
    assert re.findall(r"<script[^>]*>", html) == ["<script>"] * 3  # plotly.js inline, no src: nothing fetched
    assert len(html) > 3e6  # plotly.js itself is ~4.7 MB
    assert "Plotly.newPlot" in html and "tsimGoTo" in html


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _screenshot(page, out, tmp_path):
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync", "--no-first-run",
                    f"--user-data-dir={tmp_path / ('profile-' + out.stem)}", "--window-size=900,700",
                    "--virtual-time-budget=15000", f"--screenshot={out}", page],
                   check=True, capture_output=True, timeout=180)
    return matplotlib.image.imread(out)[..., :3]


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (.ci/run installs Debian's)")
def test_page_in_a_real_browser_shows_the_structure_and_the_slider_moves_it(page, tmp_path):
    start = _screenshot(page.as_uri(), tmp_path / "start.png", tmp_path)
    moved = _screenshot(page.as_uri() + "#t=2.5", tmp_path / "moved.png", tmp_path)
    view = (slice(100, 520), slice(100, 750))  # the 3-D scene, away from the legend and colour bar
    # not blank: the struts are drawn (dark pixels) in the scene
    assert (start[view].mean(axis=2) < 0.3).mean() > 0.002
    # the slider's step to 2.5 s (all cables slack, the prism loose) moves the structure
    assert np.abs(start[view] - moved[view]).max(axis=2).mean() > 0.005
    assert not np.array_equal(start[500:], moved[500:])  # the slider itself moved too


def test_contacts_show_on_the_time_line_and_in_the_page(demo, tmp_path):
    """Contacts from 0.5 s to 1.0 s (s0, s1) and from 2.0 s to the end (s1, s2), and a ground plane,
    put into the record (the scene format has no ground yet)."""
    record = read_log(demo[0])
    p, n = np.array([0.1, 0.2, 0.3]), np.array([1.0, 0.0, 0.0])
    events = (ContactEvent("begin", ("s0", "s1"), 0.5, p, p + 0.01, n, -1e-3),
              ContactEvent("end", ("s0", "s1"), 1.0, p, p + 0.01, n, 1e-13),
              ContactEvent("begin", ("s1", "s2"), 2.0, -p, -p, n, -2e-3))
    record = replace(record, contacts=events, ground=-0.25)
    plot_contacts(record, tmp_path)
    svg = (tmp_path / "contacts.svg").read_text()
    assert "s0 - s1" in svg and "s1 - s2" in svg and "no contact" not in svg
    picked = frame_indices(record)
    fig = build_figure(record, picked)
    for frame, k in zip(fig.frames, picked):
        t = record.times[k]
        expected = ([p, p + 0.01] if 0.5 <= t < 1.0 else []) + ([-p, -p] if t >= 2.0 else [])
        contacts = frame.data[3]
        np.testing.assert_allclose(np.column_stack([contacts.x, contacts.y, contacts.z]).reshape(-1, 3),
                                   np.array(expected, dtype=np.float32).reshape(-1, 3))
    [ground] = [trace for trace in fig.data if trace.name == "ground"]
    assert np.all(np.array(ground.z) == -0.25) and fig.layout.scene.zaxis.range[0] <= -0.25


def test_many_cables_show_the_twelve_that_snap_most(tmp_path):
    """The icosahedron (24 cables), kicked: the rows are the 12 cables first by snaps, then by tension."""
    schedule = tmp_path / "kick.yaml"
    schedule.write_text("- time: 0.05\n  forces: {n0: [0.0, 0.0, 400.0]}\n"
                        "- time: 0.1\n  forces: {n0: [0.0, 0.0, 0.0]}\n")
    log = tmp_path / "ico.mcap"
    assert main(["run", "icosahedron", "--duration", "1.0", "--quiet", "--log", str(log),
                 "--commands", str(schedule)]) == 0
    record = read_log(log)
    snaps = [int(np.sum(record.snaps[1] == c)) for c in range(24)]
    assert sum(snaps) > 0
    ranked = sorted(range(24), key=lambda c: (-snaps[c], -record.tensions[:, c].max(), c))
    shown, note = shown_cables(record)
    assert shown.tolist() == sorted(ranked[:12]) and note == "12 of 24 cables: those that snap most"
