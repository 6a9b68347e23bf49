"""A run as one self-contained HTML page with an animated 3-D view (``tensegrity-sim view LOG``).

The page is plotly's offline HTML: plotly.js is embedded from the installed ``plotly`` wheel
(``include_plotlyjs=True``), so it opens from disk with no server and no network. It shows struts
(thick dark lines), taut cables coloured by tension (colour bar in N), slack cables dashed grey, fixed
nodes as squares, the ground plane when the scene has one and the members' closest points while a
contact lasts (red). Play / pause, playback speeds, a time slider; ``page.html#t=2.5`` opens at the
frame nearest 2.5 s (through the slider's own step, so a link can point at a moment).

Frames are the log's publications, subsampled so that the page stays small and plays smoothly: at most
:data:`MAX_FRAMES` frames and :data:`MAX_VALUES` coordinates in all frames together (coordinates are
float32, to 0.1 um over a 10 m structure: far below a pixel).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import plotly.graph_objects as go

from .record import RunRecord

__all__ = ["MAX_FRAMES", "MAX_VALUES", "SPEEDS", "frame_indices", "write_page"]

MAX_FRAMES = 400          # a slider with more steps than this is no finer to the hand
MAX_VALUES = 1_500_000    # float32 values of all frames: ~8 MB of base64 beside plotly.js (~4.7 MB)
SPEEDS = (0.25, 1.0, 4.0)  # playback speeds offered, simulated seconds per wall-clock second


def frame_indices(record: RunRecord, max_frames: int = MAX_FRAMES, max_values: int = MAX_VALUES) -> np.ndarray:
    """Indices into ``record.times`` of the frames: every k-th publication from the first, and the last,
    with the smallest k that keeps within ``max_frames`` frames and ``max_values`` values in all."""
    n_values = 9 * (len(record.scene.struts) + len(record.scene.cables)) + 3 * len(record.scene.cables)
    count = len(record.times)
    allowed = max(2, min(max_frames, max_values // n_values))
    picked = np.arange(0, count, max(1, math.ceil((count - 1) / (allowed - 1))))
    return picked if picked[-1] == count - 1 else np.append(picked, count - 1)


def _segments(ends: np.ndarray) -> np.ndarray:
    """(3k, 3) float32 points of the line segments whose end points are ``ends`` (k, 2, 3), a NaN point after
    each so that the segments are not joined."""
    pts = np.full((len(ends), 3, 3), np.nan, dtype=np.float32)
    pts[:, :2] = ends
    return pts.reshape(-1, 3)


def _frame_traces(record: RunRecord, k: int, system, active: list) -> list:
    """The four animated traces at publication ``k``: struts, taut cables, slack cables (a cable attached along
    a strut drawn from there: ``System.cable_points``), contacts."""
    x = record.positions[k]
    slack = record.slack[k]
    cables = system.cable_points(x)
    struts = _segments(x[system.strut_ends])
    taut = _segments(cables[~slack])
    loose = _segments(cables[slack])
    color = np.repeat(record.tensions[k][~slack].astype(np.float32), 3)
    points = np.array([p for e in active for p in (e.point_a, e.point_b)], dtype=np.float32).reshape(-1, 3)
    return [go.Scatter3d(x=struts[:, 0], y=struts[:, 1], z=struts[:, 2]),
            go.Scatter3d(x=taut[:, 0], y=taut[:, 1], z=taut[:, 2], line={"color": color}),
            go.Scatter3d(x=loose[:, 0], y=loose[:, 1], z=loose[:, 2]),
            go.Scatter3d(x=points[:, 0], y=points[:, 1], z=points[:, 2])]


def _active_contacts(record: RunRecord, picked: np.ndarray) -> list[list]:
    """For each picked publication, the contact events (their ``begin``) going on at its time."""
    out, active, events = [], {}, list(record.contacts)
    i = 0
    for k in picked:
        while i < len(events) and events[i].time <= record.times[k]:
            e = events[i]
            if e.kind == "begin":
                active[e.members] = e
            else:
                active.pop(e.members, None)
            i += 1
        out.append(list(active.values()))
    return out


def _animate_args(name: str | None, frame_ms: float) -> list:
    mode = {"frame": {"duration": frame_ms, "redraw": True}, "mode": "immediate", "transition": {"duration": 0},
            "fromcurrent": True}
    return [None if name is None else [name], mode]


# Open at the frame in the URL's #t=SECONDS, through the slider's own step (written here, not copied).
_HASH_SCRIPT = """
var gd = document.getElementById('{plot_id}');
function tsimGoTo() {
  var m = /t=([0-9.eE+-]+)/.exec(window.location.hash);
  if (!m) { return; }
  var steps = gd.layout.sliders[0].steps, t = parseFloat(m[1]), best = 0;
  for (var i = 0; i < steps.length; i++) {
    if (Math.abs(steps[i].value - t) < Math.abs(steps[best].value - t)) { best = i; }
  }
  Plotly.animate(gd, steps[best].args[0], steps[best].args[1]);
  Plotly.relayout(gd, {'sliders[0].active': best});
}
tsimGoTo();
window.addEventListener('hashchange', tsimGoTo);
"""


def build_figure(record: RunRecord, picked: np.ndarray) -> go.Figure:
    """The animated figure of ``record`` at the publications ``picked``."""
    system = record.system
    active = _active_contacts(record, picked)
    t_max = float(max(record.tensions.max(initial=0.0), 1e-12))
    lo, hi = record.positions.min(axis=(0, 1)), record.positions.max(axis=(0, 1))
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-3)
    lo, hi = lo - pad, hi + pad
    if record.ground is not None:
        lo[2], hi[2] = min(lo[2], record.ground), max(hi[2], record.ground)
    first = _frame_traces(record, int(picked[0]), system, active[0])
    first[0].update(mode="lines", name="struts", line={"color": "#303030", "width": 9}, hoverinfo="skip")
    first[1].update(mode="lines", name="taut cables (tension)", hoverinfo="skip",
                    line={"width": 5, "colorscale": "Plasma", "cmin": 0.0, "cmax": t_max, "showscale": True,
                          "colorbar": {"title": {"text": "tension (N)"}, "len": 0.6}})
    first[2].update(mode="lines", name="slack cables", line={"color": "#9a9a9a", "width": 3, "dash": "dash"},
                    hoverinfo="skip")
    first[3].update(mode="markers", name="contacts", marker={"color": "red", "size": 6}, hoverinfo="skip")
    fixed = record.positions[0][~system.free]
    static = [go.Scatter3d(x=fixed[:, 0], y=fixed[:, 1], z=fixed[:, 2], mode="markers", name="fixed nodes",
                           marker={"symbol": "square", "color": "#555555", "size": 5}, hoverinfo="skip")]
    if record.ground is not None:
        static.append(go.Surface(x=[lo[0], hi[0]], y=[lo[1], hi[1]], z=[[record.ground] * 2] * 2, name="ground",
                                 showscale=False, opacity=0.35, colorscale=[[0, "#8c7b5a"], [1, "#8c7b5a"]],
                                 hoverinfo="skip", showlegend=True))
    names = [f"{record.times[k]:.3f}" for k in picked]
    frames = [go.Frame(name=name, data=_frame_traces(record, int(k), system, a), traces=[0, 1, 2, 3])
              for name, k, a in zip(names, picked, active)]
    frame_s = float(record.times[picked[1]] - record.times[picked[0]]) if len(picked) > 1 else 0.1
    buttons = [{"label": "Pause", "method": "animate", "args": [[None], {"frame": {"duration": 0, "redraw": False},
                                                                        "mode": "immediate"}]}]
    buttons += [{"label": f"Play {s:g}x", "method": "animate", "args": _animate_args(None, 1000.0 * frame_s / s)}
                for s in SPEEDS]
    size = hi - lo
    fig = go.Figure(data=first + static, frames=frames)
    fig.update_layout(
        title={"text": f"{record.title} - {len(picked)} frames, one every {frame_s:g} s of simulated time"},
        scene={"xaxis": {"range": [lo[0], hi[0]], "title": {"text": "x (m)"}},
               "yaxis": {"range": [lo[1], hi[1]], "title": {"text": "y (m)"}},
               "zaxis": {"range": [lo[2], hi[2]], "title": {"text": "z (m)"}},
               "aspectmode": "manual", "aspectratio": dict(zip("xyz", (size / size.max()).tolist()))},
        legend={"x": 0.0, "y": 1.0},
        margin={"l": 0, "r": 0, "t": 50, "b": 0},
        updatemenus=[{"type": "buttons", "direction": "left", "x": 0.0, "y": 0.0, "xanchor": "left",
                      "yanchor": "top", "pad": {"t": 40}, "showactive": True, "buttons": buttons}],
        sliders=[{"active": 0, "x": 0.34, "len": 0.64, "y": 0.0, "yanchor": "top", "pad": {"t": 30},
                  "currentvalue": {"prefix": "t = ", "suffix": " s"},
                  "steps": [{"label": name, "value": name, "method": "animate",
                             "args": _animate_args(name, 0.0)} for name, k in zip(names, picked)]}],
    )
    return fig


def write_page(record: RunRecord, out: str | Path, *, max_frames: int = MAX_FRAMES,
               max_values: int = MAX_VALUES) -> tuple[Path, int]:
    """Write the page of ``record`` to ``out`` (its directory created); (path, number of frames)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    picked = frame_indices(record, max_frames, max_values)
    fig = build_figure(record, picked)
    fig.write_html(out, include_plotlyjs=True, full_html=True, auto_play=False, div_id="tensegrity-view",
                   post_script=_HASH_SCRIPT, config={"displaylogo": False, "responsive": True})
    return out, len(picked)
