"""MkDocs hooks (``hooks:`` in mkdocs.yml): what the site generates at build time so that it cannot go stale.

* ``{{ table("x.csv", columns=..., where=..., digits=3) }}`` on a page becomes the Markdown table of
  ``bench/results/x.csv`` with its provenance (command, commit, date, machine) under it
  (``bench.tables.markdown_table``: ``columns`` a list or a {column: header} mapping, ``where`` a
  {column: value or [values]} filter). A new CSV needs no code here: name it on a page.
* ``{{ value("x.csv", "column", where={...}, digits=3) }}`` becomes one cell of one row (exactly one row
  must match), for a figure in a sentence.
* ``{{ source("x.csv") }}`` becomes the provenance line alone (for a figure of the CSV's run).
* ``figures/scenes/<name>.png``: every built-in scene drawn from its YAML (struts thick, cables thin).
* ``bench-results/<path>.png``: every figure the benchmarks drew into ``bench/results/``, as they are.
* ``ros/interface/<page>.md``: every page of ``msg_docs/``, included as it is (the node's interface has one
  source: the files installed with the package).
* The API pages: the docstrings' Sphinx roles (``:func:``, ``:class:``, ...) dropped before the code they name.

Macros inside code (fenced blocks, code spans) are shown as written. A macro that names a missing file,
column or row fails the build (``PluginError``): a page never shows a figure that its CSV no longer holds.
"""
from __future__ import annotations

import ast
import io
import re
import sys
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.tables import RESULTS, cell, markdown_table, read_csv, select, source_line  # noqa: E402

MACRO = re.compile(r"\{\{\s*(table|value|source)\((.*?)\)\s*\}\}", re.S)
ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj):<code>~?")
CODE = re.compile(r"(^```.*?^```|`[^`\n]+`)", re.S | re.M)   # fenced blocks and code spans: shown, not expanded
MSG_DOCS = ROOT / "msg_docs"


def _arguments(text: str) -> tuple[list, dict]:
    """The positional and keyword arguments of a macro call, as Python literals."""
    call = ast.parse(f"f({text})", mode="eval").body
    return [ast.literal_eval(a) for a in call.args], {k.arg: ast.literal_eval(k.value) for k in call.keywords}


def _csv(name: str) -> Path:
    path = RESULTS / name
    if not path.exists():
        raise ValueError(f"no {path.relative_to(ROOT)} (bench/ writes it)")
    return path


def _value(name: str, column: str, where: dict | None = None, digits: int = 3) -> str:
    rows = select(read_csv(_csv(name)), where)
    if len(rows) != 1:
        raise ValueError(f"{name}: {len(rows)} rows match {where}, not one")
    if column not in rows[0]:
        raise ValueError(f"{name}: no column {column!r}")
    return cell(rows[0][column], digits)


def _expand(match: re.Match, page: str) -> str:
    """The macro's text; a table indented as the macro is (inside a list item it stays in the item)."""
    kind, text = match.groups()
    line_start = match.string.rfind("\n", 0, match.start()) + 1
    indent = match.string[line_start:match.start()]
    try:
        args, kwargs = _arguments(text)
        if kind == "table":
            table = markdown_table(_csv(args[0]), *args[1:], **kwargs).rstrip("\n")
            return table.replace("\n", "\n" + indent) if indent.isspace() else table
        if kind == "value":
            return _value(*args, **kwargs)
        return source_line(_csv(args[0]))
    except (ValueError, SyntaxError, TypeError, IndexError) as error:
        raise PluginError(f"{page}: {match.group(0)!r}: {error}") from error


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Every macro of the page, outside code, replaced by what the CSVs hold now."""
    parts = CODE.split(markdown)   # odd indices: the code
    return "".join(part if i % 2 else MACRO.sub(lambda m: _expand(m, page.file.src_uri), part)
                   for i, part in enumerate(parts))


def on_page_content(html: str, page, config, files) -> str:
    """The docstrings' Sphinx roles (``:func:`name```, ``:class:`~a.b.C```) shown as the code they name: the
    API pages render the docstrings as Markdown, which leaves the role's prefix in the text."""
    return ROLE.sub("<code>", html)


def _scene_figure(name: str) -> bytes:
    """A built-in scene drawn in 3-D from its YAML: struts thick and dark, cables thin and blue, fixed nodes
    as squares, names of nodes beside them for small scenes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import tensegrity_sim as ts

    scene = ts.load_scene(name)
    positions = np.array([node.position for node in scene.nodes])
    index = {node.name: i for i, node in enumerate(scene.nodes)}
    fig = plt.figure(figsize=(4.2, 4.2))
    ax = fig.add_subplot(projection="3d")
    for members, style in ((scene.cables, dict(color="tab:blue", lw=0.8)), (scene.struts, dict(color="0.15", lw=2.6))):
        for member in members:
            a, b = (positions[index[n]] for n in member.nodes)
            ax.plot(*np.stack([a, b]).T, **style)
    ax.scatter(*positions.T, s=6, color="0.15")
    if len(scene.nodes) <= 12:
        for node, p in zip(scene.nodes, positions):
            ax.text(*p, f" {node.name}", fontsize=7)
    span = (positions.max(axis=0) - positions.min(axis=0)).max() / 2
    centre = (positions.max(axis=0) + positions.min(axis=0)) / 2
    for axis, c in zip("xyz", centre):
        getattr(ax, f"set_{axis}lim")(c - span, c + span)
    ax.set_box_aspect((1, 1, 1))
    counts = f"{len(scene.nodes)} nodes, {len(scene.struts)} struts, {len(scene.cables)} cables"
    ax.set_title(f"{name}: {counts}", fontsize=9)
    ax.tick_params(labelsize=6)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def on_files(files, config):
    """The generated files: the built-in scenes' figures, bench/results/'s figures and the msg_docs pages."""
    import tensegrity_sim as ts

    for name in ts.builtin_scenes():
        files.append(File.generated(config, f"figures/scenes/{name}.png", content=_scene_figure(name)))
    for figure in sorted(RESULTS.rglob("*.png")):
        files.append(File.generated(config, f"bench-results/{figure.relative_to(RESULTS).as_posix()}",
                                    abs_src_path=str(figure)))
    for page in sorted(MSG_DOCS.glob("*.md")):
        files.append(File.generated(config, f"ros/interface/{page.name}", abs_src_path=str(page)))
    return files
