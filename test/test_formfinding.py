"""Form-finding of the built-in scenes: exact equilibrium, taut cables, compressed struts, sizes."""
import re
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from tensegrity_sim import formfinding as ff

SCENES_DIR = Path(ff.__file__).resolve().parent / "scenes"
SHIPPED = {"prism3": ff.prism, "icosahedron": ff.icosahedron, "tower": ff.tower}
# on the ground, held by friction (test_builtins.py holds them at rest with both methods)
ON_THE_GROUND = {"superball": ff.superball, "three_bar": ff.three_bar}
NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def shipped(name):
    return yaml.safe_load((SCENES_DIR / f"{name}.yaml").read_text())


def scenes_under_test():
    return [pytest.param(name, shipped(name), id=name) for name in SHIPPED] + [
        pytest.param("tower10", ff.tower(10), id="tower10")
    ]


@pytest.mark.parametrize("name,scene", scenes_under_test())
def test_exact_equilibrium(name, scene):
    assert ff.equilibrium_residual(scene) < 1e-9


@pytest.mark.parametrize("name,scene", scenes_under_test())
def test_cables_taut_struts_compressed(name, scene):
    forces = ff.member_forces(scene)
    # "taut with a clear margin": far above round-off, not merely > 0
    assert min(forces["cables"].values()) > 10.0
    # elastic struts and (solved) rigid struts alike push
    assert max(forces["struts"].values()) < -10.0
    for m in scene["struts"]:
        if m["stiffness"] != "rigid":
            assert m["rest_length"] > np.linalg.norm(
                np.subtract(*[next(n["position"] for n in scene["nodes"] if n["name"] == e) for e in m["nodes"]])
            )
    assert all(m["rest_length"] > 0 for m in scene["struts"] + scene["cables"])


@pytest.mark.parametrize("name,scene", scenes_under_test())
def test_schema_names_radii_and_clearance(name, scene):
    assert set(scene) == {"name", "gravity", "nodes", "struts", "cables"}
    names = [e["name"] for e in scene["nodes"] + scene["struts"] + scene["cables"]]
    assert all(NAME.match(n) for n in names) and len(set(names)) == len(names)
    assert all(0.01 <= s["radius"] <= 0.03 for s in scene["struts"])
    assert all(0.002 <= c["radius"] <= 0.005 for c in scene["cables"])
    # at most one strut per node (no class-k warning)
    ends = [e for s in scene["struts"] for e in s["nodes"]]
    assert len(ends) == len(set(ends))
    # no two members that share no node touch at the start (contact detection starts quiet)
    X, _, _, members, _, _, _ = ff._parse(scene)
    radii = np.array([m["radius"] for m in scene["struts"] + scene["cables"]])
    assert ff._min_clearance(X, members, radii) > 0.01


@pytest.mark.parametrize("name", [*SHIPPED, *ON_THE_GROUND])
def test_shipped_files_are_up_to_date(name):
    """The YAML files are what the generator produces now (regenerate: python -m tensegrity_sim.formfinding)."""
    text = (SCENES_DIR / f"{name}.yaml").read_text()
    assert text.startswith("# GENERATED FILE") and "python -m tensegrity_sim.formfinding" in text
    on_disk, fresh = shipped(name), {**SHIPPED, **ON_THE_GROUND}[name]()
    assert yaml.safe_dump(on_disk) == yaml.safe_dump(fresh) or (
        # tolerate a last-bit libm difference between machines in the trigonometry
        [n["name"] for n in on_disk["nodes"]] == [n["name"] for n in fresh["nodes"]]
        and np.allclose([n["position"] for n in on_disk["nodes"]], [n["position"] for n in fresh["nodes"]],
                        rtol=0, atol=1e-12)
    )


def test_prism_geometry():
    scene = shipped("prism3")
    assert len(scene["nodes"]) == 6 and len(scene["struts"]) == 3 and len(scene["cables"]) == 9
    assert scene["gravity"] == [0.0, 0.0, 0.0]
    assert not any(n.get("fixed") for n in scene["nodes"])
    X = {n["name"]: np.array(n["position"]) for n in scene["nodes"]}
    for s in scene["struts"]:
        assert np.linalg.norm(X[s["nodes"][1]] - X[s["nodes"][0]]) == pytest.approx(1.0, abs=1e-12)
    # explicit Verlet at 1 ms stays well inside its stability limit on the strut mode
    for s in scene["struts"]:
        assert np.sqrt(2 * s["stiffness"] / 0.5) * 1e-3 < 0.5


def test_icosahedron_superball_numbers():
    scene = shipped("icosahedron")
    assert len(scene["nodes"]) == 12 and len(scene["struts"]) == 6 and len(scene["cables"]) == 24
    assert scene["gravity"] == [0.0, 0.0, 0.0]
    X = {n["name"]: np.array(n["position"]) for n in scene["nodes"]}
    for s in scene["struts"]:
        assert s["stiffness"] == "rigid"
        assert np.linalg.norm(X[s["nodes"][1]] - X[s["nodes"][0]]) == pytest.approx(1.684, abs=1e-12)
        assert not s.get("mass")
    assert all(n["mass"] == 1.75 and not n.get("fixed") for n in scene["nodes"])
    assert all(c["stiffness"] == 613.0 for c in scene["cables"])
    lengths = [np.linalg.norm(X[c["nodes"][1]] - X[c["nodes"][0]]) for c in scene["cables"]]
    assert np.ptp(lengths) < 1e-12  # symmetric: all 24 cables equally long ...
    tensions = list(ff.member_forces(scene)["cables"].values())
    assert np.allclose(tensions, 80.0, rtol=1e-9)  # ... and equally tensioned


@pytest.mark.parametrize("stages", [1, 2, 3, 7])
def test_tower_counts(stages):
    scene = ff.tower(stages)
    assert len(scene["nodes"]) == 6 * stages
    assert len(scene["struts"]) == 3 * stages
    assert len(scene["cables"]) == 24 * stages - 15
    assert sum(bool(n.get("fixed")) for n in scene["nodes"]) == 3
    assert scene["gravity"] == [0.0, 0.0, -9.81]
    assert ff.equilibrium_residual(scene) < 1e-9


def test_shipped_tower_is_three_stages():
    scene = shipped("tower")
    assert len(scene["nodes"]) == 18 and sum(bool(n.get("fixed")) for n in scene["nodes"]) == 3


def test_tower_stable_up_to_15_stages_and_warns_beyond():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the stability check would warn if the tangent stiffness were not PD
        ff.tower(10)
        ff.tower(15)
    with pytest.warns(RuntimeWarning, match="unstable"):
        ff.tower(20)


def test_tower_100_stages_fast():
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = ff.tower(100, gravity=(0.0, 0.0, 0.0))  # prestress only: stable at any height
    assert time.perf_counter() - start < 10.0
    assert len(scene["nodes"]) == 600
    assert ff.equilibrium_residual(scene) < 1e-9
    assert min(ff.member_forces(scene)["cables"].values()) > 10.0


def test_residual_sees_imbalance():
    scene = ff.prism()
    scene["cables"][0]["rest_length"] -= 1e-3  # 2 N more tension in one cable
    assert ff.equilibrium_residual(scene) > 1.0


def test_tower_rejects_bad_stages():
    with pytest.raises(ValueError):
        ff.tower(0)
