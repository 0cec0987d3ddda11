"""The kinematic tree: which adjacent links share a joint (artrecon.joints.build_kinematic_tree).

Each pair of adjacent links is scored by how well one joint located where they touch explains
their relative motion; siblings that touch each other more than their parent must not be chained.
"""

import numpy as np
import pytest
from synthetic import make_sibling_fingers

from artrecon.joints import JointConfig, build_kinematic_tree
from artrecon.segment import Segmentation


def _tree(obj, config=JointConfig()):  # noqa: B008
    seg = Segmentation(labels=obj.labels, transforms=obj.link_motions, scale=1.0)
    return build_kinematic_tree(obj.points_a, seg, config)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_touching_siblings_hang_on_their_parent(seed):
    """Barrett-hand-like: two fingers spread on a palm; their tips face each other closer than
    either finger stands on the palm, and their relative motion is a clean rotation whose axis
    passes nearer the fingers than each finger's own axis does (the palm under a knuckle is
    hidden). Only where the axis runs with respect to the contact tells the tree: each finger's
    axis runs through its knuckle's rim on the palm, the fingers' relative axis 6 cm from their
    touching tips."""
    obj = make_sibling_fingers(seed)
    tree = _tree(obj)
    # the siblings touch each other more closely than they touch the palm
    assert tree.gaps[1, 2] < min(tree.gaps[0, 1], tree.gaps[0, 2])
    fig = tree.edge_figures
    # their relative motion is one clean hinge (no slide), by twice the spread
    assert fig[(1, 2)]["type"] == "revolute"
    assert fig[(1, 2)]["misfit"] < 1e-9
    assert fig[(1, 2)]["angle_deg"] == pytest.approx(60.0, abs=1e-6)
    assert tree.root == 0
    assert sorted(tree.edges) == [(0, 1), (0, 2)]
    assert list(tree.parents) == obj.parents
    # ... because that axis runs far from where the fingers touch, the true ones through it
    assert fig[(1, 2)]["axis_contact"] > 0.05
    assert max(fig[(0, 1)]["axis_contact"], fig[(0, 2)]["axis_contact"]) < 0.025
    assert not fig[(1, 2)]["in_tree"] and fig[(0, 1)]["in_tree"] and fig[(0, 2)]["in_tree"]
    # not by a hair: the next best tree (the siblings chained) costs clearly more
    costs = {k: v["cost"] for k, v in fig.items()}
    assert tree.margin == pytest.approx(costs[(1, 2)] - max(costs[(0, 1)], costs[(0, 2)]))
    assert tree.margin > 0.3


def test_axis_to_whole_links_chains_the_siblings():
    """The same fingers scored by the axis' distance to the links as wholes (a contact band as
    wide as the object): the siblings' relative axis passes nearer both fingers than each true
    axis passes its post and the palm, so the fingers get chained. The contact is what counts."""
    obj = make_sibling_fingers(0)
    blind = _tree(obj, JointConfig(contact_margin=100.0))
    assert sorted(blind.edges) != [(0, 1), (0, 2)]
    assert (1, 2) in {tuple(sorted(e)) for e in blind.edges}


def test_tree_margin_and_edge_figures_of_a_pair():
    """Two links: one possible tree (margin inf), its one edge's figures recorded."""
    obj = make_sibling_fingers(0)
    keep = obj.labels < 2
    seg = Segmentation(labels=obj.labels[keep], transforms=obj.link_motions[:2], scale=1.0)
    tree = build_kinematic_tree(obj.points_a[keep], seg)
    assert tree.edges == [(0, 1)]
    assert tree.margin == np.inf
    fig = tree.edge_figures[(0, 1)]
    assert fig["in_tree"] and fig["type"] == "revolute"
    assert fig["angle_deg"] == pytest.approx(30.0, abs=1e-6)
    assert min(fig["contact"]) >= 3
