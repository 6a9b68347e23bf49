"""Scene loading: round trips, built-ins, and every refusal with its exact message."""
import copy
import math

import pytest
import yaml

import tensegrity_sim as ts
from conftest import bungee_dict

BASE = {
    "name": "t",
    "nodes": [
        {"name": "n0", "position": [0.0, 0.0, 0.0], "mass": 1.0},
        {"name": "n1", "position": [1.0, 0.0, 0.0], "mass": 1.0},
        {"name": "n2", "position": [0.0, 1.0, 0.0], "mass": 1.0},
    ],
    "struts": [{"name": "s0", "nodes": ["n0", "n1"], "stiffness": 1.0e4}],
    "cables": [
        {"name": "c0", "nodes": ["n1", "n2"], "stiffness": 100.0, "rest_length": 1.2},
        {"name": "c1", "nodes": ["n2", "n0"], "stiffness": 100.0},
    ],
}


def edited(path, value):
    d = copy.deepcopy(BASE)
    target = d
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return d


REFUSED = [
    (edited(["cables", 0, "stiffness"], -5.0), "cables[0] 'c0': stiffness must be > 0, got -5.0"),
    (edited(["cables", 0, "rest_length"], 0.0), "cables[0] 'c0': rest_length must be > 0, got 0.0"),
    (edited(["cables", 0, "rest_length"], math.nan), "cables[0] 'c0': rest_length must be finite, got nan"),
    (edited(["nodes", 1, "position"], [1.0, math.inf, 0.0]), "nodes[1] 'n1': position must be finite, got inf"),
    (edited(["nodes", 1, "position"], [1.0, 0.0]), "nodes[1] 'n1': position must be a list of 3 numbers, got [1.0, 0.0]"),
    (edited(["nodes", 1, "colour"], "red"), "nodes[1] 'n1': unknown key 'colour' (allowed: fixed, mass, name, position, radius, velocity)"),
    (edited(["colour"], "red"), "unknown key 'colour' (allowed: cables, contact, gravity, ground, name, nodes, struts)"),
    (edited(["nodes", 2, "name"], "n0"), "nodes[2] 'n0': duplicate name 'n0'"),
    (edited(["cables", 1, "name"], "s0"), "cables[1] 's0': duplicate name 's0'"),
    (edited(["nodes", 2, "name"], "2bad"), "nodes[2] '2bad': name must match [A-Za-z_][A-Za-z0-9_]*, got '2bad'"),
    (edited(["cables", 0, "nodes"], ["n1", "n9"]), "cables[0] 'c0': nodes: unknown node 'n9'"),
    (edited(["cables", 0, "nodes"], ["n1", "n1"]), "cables[0] 'c0': nodes: a member cannot join node 'n1' to itself"),
    (edited(["nodes", 2, "position"], [1.0, 0.0, 0.0]), "cables[0] 'c0': nodes: zero-length member ('n1' and 'n2' coincide)"),
    (edited(["nodes", 2, "mass"], KeyError), "nodes[2] 'n2': mass must be > 0 for a free node, got 0.0"),
    (edited(["nodes", 2, "mass"], -1.0), "nodes[2] 'n2': mass must be >= 0, got -1.0"),
    (edited(["struts", 0, "stiffness"], "soft"), "struts[0] 's0': stiffness must be a number, got 'soft'"),
    (edited(["struts", 0, "stiffness"], KeyError), "struts[0] 's0': missing required key 'stiffness'"),
    (edited(["cables", 0, "damping"], -0.1), "cables[0] 'c0': damping must be >= 0, got -0.1"),
    (edited(["cables", 0, "radius"], -0.1), "cables[0] 'c0': radius must be >= 0, got -0.1"),
    (edited(["gravity"], [0, 0]), "scene: gravity must be a list of 3 numbers, got [0, 0]"),
    (edited(["nodes"], []), "nodes: must be a non-empty list"),
    (edited(["nodes", 0, "fixed"], "yes"), "nodes[0] 'n0': fixed must be true or false, got 'yes'"),
    # issue 13: what escaped as another exception, or was accepted silently
    (edited(["nodes", 2, "name"], "n2\n"), "nodes[2] 'n2\\n': name must match [A-Za-z_][A-Za-z0-9_]*, got 'n2\\n'"),
    (edited(["nodes", 2, "mass"], 10 ** 400), "nodes[2] 'n2': mass is too large for a float: an integer of 401 digits"),
    (edited(["nodes", 2, "position"], [-1e308, 1.0, 0.0]), "cables[0] 'c0': nodes: the distance from 'n1' to 'n2' "
     "overflows the float range (ends at [1.0, 0.0, 0.0] and [-1e+308, 1.0, 0.0] m)"),
    (edited(["nodes", 1, "position"], [1e308, 0.0, 0.0]), "struts[0] 's0': nodes: the distance from 'n0' to 'n1' "
     "overflows the float range (ends at [0.0, 0.0, 0.0] and [1e+308, 0.0, 0.0] m)"),
    (edited(["nodes", 1, "mass"], 1.7e308) | {"struts": [{"name": "s0", "nodes": ["n0", "n1"], "stiffness": 1.0e4,
                                                          "mass": 1.7e308}]},
     "nodes[1] 'n1': its mass plus its share of its struts' masses overflows the float range"),
    # issue 46: rods with their mass along them, payloads, end caps
    (edited(["struts", 0, "mass_distribution"], "middle"),
     "struts[0] 's0': mass_distribution must be one of uniform, ends, got 'middle'"),
    (edited(["struts", 0, "payloads"], [{"at": 1.5, "mass": 1.0}]),
     "struts[0] 's0' payloads[0]: at must be in [0, 1], got 1.5"),
    (edited(["struts", 0, "payloads"], [{"at": 0.5, "mass": -2.0}]),
     "struts[0] 's0' payloads[0]: mass must be >= 0, got -2.0"),
    (edited(["struts", 0, "payloads"], [{"at": 0.5}]), "struts[0] 's0' payloads[0]: missing required key 'mass'"),
    (edited(["struts", 0, "payloads"], {"at": 0.5, "mass": 1.0}),
     "struts[0] 's0': payloads must be a list of {at, mass} mappings, got {'at': 0.5, 'mass': 1.0}"),
    (edited(["nodes", 0, "radius"], -0.01), "nodes[0] 'n0': radius must be >= 0, got -0.01"),
    (edited(["nodes", 1, 7], 1.0), "nodes[1] 'n1': unknown key 7 (allowed: fixed, mass, name, position, radius, velocity)"),
    (edited(["struts", 0, "stiffness"], ["rigid"]), "struts[0] 's0': stiffness must be a number, got ['rigid']"),
    (edited(["nodes", 0, "position"], [[[[[[1]]]]], 0, 0]),
     "nodes[0] 'n0': position must be a number, got [[[[...]]]]"),
]


@pytest.mark.parametrize("mapping, message", REFUSED, ids=[m for _, m in REFUSED])
def test_refused_with_exact_message(mapping, message):
    with pytest.raises(ts.SceneError) as err:
        ts.Scene.from_dict(mapping, source="bad.yaml")
    assert str(err.value) == f"bad.yaml: {message}"


def test_refused_file_names_the_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(edited(["cables", 0, "stiffness"], -5.0)))
    with pytest.raises(ts.SceneError, match=r"broken\.yaml: cables\[0\] 'c0': stiffness must be > 0, got -5.0"):
        ts.load_scene(path)


@pytest.mark.parametrize("text", ["[" * 2000 + "]" * 2000, "nodes: " + "[" * 100_000, "{a: " * 2000 + "1" + "}" * 2000,
                                  "- " * 100_000 + "1"], ids=["flow", "flow-open", "mappings", "block"])
def test_deep_yaml_refused_naming_the_file(tmp_path, text):
    path = tmp_path / "deep.yaml"
    path.write_text(text)
    with pytest.raises(ts.SceneError, match=rf"^{tmp_path}/deep\.yaml: not valid YAML: nested deeper than 64 levels"):
        ts.load_scene(path)


@pytest.mark.parametrize("text, reason", [
    ("name: 1" + ":00" * 200 + ".0", "(OverflowError: int too large to convert to float)"),
    ("name: !!timestamp 99999-01-01", "(AttributeError: 'NoneType' object has no attribute 'groupdict')"),
    ("name: 0000-01-01", "(ValueError: year 0 is out of range)"),
], ids=["sexagesimal", "timestamp", "year-0"])
def test_values_pyyaml_cannot_build_are_refused_naming_the_file(tmp_path, text, reason):
    """Issue 13: these escaped from PyYAML as OverflowError, AttributeError and ValueError."""
    path = tmp_path / "odd.yaml"
    path.write_text(text)
    with pytest.raises(ts.SceneError) as err:
        ts.load_scene(path)
    assert str(err.value) == f"{path}: a value cannot be read {reason}"


def test_non_utf8_file_refused_naming_the_file(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\u00e9\n".encode("latin-1"))
    with pytest.raises(ts.SceneError) as err:
        ts.load_scene(path)
    assert str(err.value) == f"{path}: not UTF-8 text (byte 9: b'\\xe9')"


def test_tiny_mass_is_refused_at_start_up():
    """A free mass so small that stiffness/mass leaves the float range: SceneError, not numpy's LinAlgError."""
    scene = ts.Scene.from_dict(edited(["nodes", 2, "mass"], 1e-310), source="tiny.yaml")
    with pytest.raises(ts.SceneError) as err:
        ts.Simulator(scene)
    assert str(err.value) == ("tiny.yaml: the members' stiffness/mass ratios are beyond the float range (stiffness "
                              "up to 1e+04 N/m; lightest free node 'n2', 1e-310 kg)")


def test_unknown_scene_lists_builtins():
    with pytest.raises(ts.SceneError, match="not a built-in scene .*prism3"):
        ts.load_scene("no_such_scene")


def test_defaults_and_lumped_masses():
    d = copy.deepcopy(BASE)
    d["struts"][0]["mass"] = 0.5
    s = ts.Scene.from_dict(d)
    assert s.cables[1].rest_length == 1.0  # default: the initial distance
    assert s.struts[0].rest_length == 1.0
    assert list(s.masses) == [1.25, 1.25, 1.0]
    assert s.gravity == (0.0, 0.0, 0.0)
    assert s.node_names == ("n0", "n1", "n2") and s.cable_names == ("c0", "c1") and s.strut_names == ("s0",)


def test_round_trip_through_dict_and_yaml():
    s = ts.Scene.from_dict(BASE)
    again = ts.Scene.from_dict(yaml.safe_load(s.to_yaml()))
    assert again == s
    rigid = ts.Scene.from_dict(edited(["struts", 0, "stiffness"], "rigid"))
    assert rigid.struts[0].rigid and rigid.to_dict()["struts"][0]["stiffness"] == "rigid"
    assert ts.Scene.from_dict(rigid.to_dict()) == rigid


def test_rigid_strut_rest_length_must_match():
    d = edited(["struts", 0, "stiffness"], "rigid")
    d["struts"][0]["rest_length"] = 0.9
    with pytest.raises(ts.SceneError, match="rest_length of a rigid strut must equal its length 1.0, got 0.9"):
        ts.Scene.from_dict(d)


def test_class_k_loads_with_warning():
    d = copy.deepcopy(BASE)
    d["struts"].append({"name": "s1", "nodes": ["n0", "n2"], "stiffness": 1.0e4})
    with pytest.warns(ts.ClassKWarning, match=r"\['n0'\] carry more than one strut"):
        s = ts.Scene.from_dict(d)
    assert len(s.struts) == 2


def test_fixed_node_needs_no_mass():
    s = ts.Scene.from_dict(bungee_dict())
    assert s.masses[0] == 0.0 and bool(s.fixed[0])


@pytest.mark.parametrize("name", ["prism3", "icosahedron", "tower"])
def test_builtins_listed_and_load(name):
    assert name in ts.builtin_scenes()
    s = ts.load_scene(name)
    assert ts.Scene.from_dict(s.to_dict()) == s
    assert all(st.radius > 0 for st in s.struts) and all(c.radius > 0 for c in s.cables)
