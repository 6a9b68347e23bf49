"""examples/roll_controller.py (issue 11): rolling icosahedron_ground through the node's topics, driven
through the node's logic without ROS, and its planner's symmetry mapping."""
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

import tensegrity_sim as ts

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import roll_controller as rc  # noqa: E402


@pytest.fixture(scope="module")
def planner():
    return rc.planner_for(ts.load_scene("icosahedron_ground"))


def test_planner_maps_the_known_roll_onto_every_triangle_and_edge(planner):
    """For each of the 8 cable triangles, each edge and each direction of it for which the graph has an
    automorphism from the known triangle and edge, the robot posed there (the scene's positions relabelled
    by it: a rotated copy) gets exactly the images of the known cables and the known landing; the known
    pose and edge give the known cables (examples/roll.yaml). Every such edge has one direction."""
    scene = ts.load_scene("icosahedron_ground")
    x = scene.positions
    index = {n: i for i, n in enumerate(planner.nodes)}
    assert len(planner.triangles) == 8
    cables, landing, edge = planner.plan(x, (-1.0, 1.0))   # n4-n8 faces (-1, 1)
    assert (sorted(cables), landing, edge) == (["c4", "c5", "c6"], ("n1", "n6", "n8"), ("n4", "n8"))
    known = [index[n] for n in rc.KNOWN_BASE]
    heading = (0.5 * (x[index["n4"]] + x[index["n8"]]) - x[known].mean(axis=0))[:2]
    kinds = planner._kind
    posed_count = 0
    for tri in planner.triangles:
        for third in tri:
            e1, e2 = [m for m in tri if m != third]
            found = [p for p in (planner._automorphism(dict(zip(known, (third, a, b)))) for a, b in ((e1, e2), (e2, e1)))
                     if p is not None]
            assert len(found) == 1
            p = found[0]
            assert sorted(p) == list(range(12))
            assert all(kinds[p[i], p[j]] == kinds[i, j] for i, j in itertools.combinations(range(12), 2))
            posed = np.empty_like(x)
            posed[p] = x   # node p[i] stands where node i stands in the scene
            cables, landing, edge = planner.plan(posed, heading)
            assert set(edge) == {planner.nodes[e1], planner.nodes[e2]}
            assert set(cables) == {planner._cable[frozenset((p[index[a]], p[index[b]]))] for a, b in rc.KNOWN_PULL}
            assert set(landing) == {planner.nodes[p[index[n]]] for n in rc.KNOWN_LANDING}
            posed_count += 1
    assert posed_count == 24


def test_one_cycle_through_the_node_rolls_onto_the_planned_triangle():
    """One command cycle through the node's logic (node_poses in, cable_rest_lengths out) with the heading
    +x: the planner picks the edge n0-n8 (not the known one: the cables are the known ones' images under a
    symmetry), and the robot lands on the triangle it planned, its centre of mass more than 0.5 m further
    along +x (measured 0.871 m: tipping over the edge moves it by about twice the 0.29 m from the centre of
    mass to the edge, horizontally, and it rocks on)."""
    controller, history = rc.drive_offline(1, heading=(1.0, 0.0))
    start, (edge, cables, landing, stood, com, _) = history[0], history[1]
    assert edge == ("n0", "n8") and sorted(cables) == ["c1", "c18", "c19"]
    assert set(stood) == set(landing) and set(stood) != set(start[3])
    assert (com - start[4])[0] > 0.5
