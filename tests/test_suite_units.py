"""The suite's own scheduling (tests/conftest.py): the gate modules split per scene."""

from conftest import LONGEST_FIRST, PER_SCENE_MODULES, scene_scope

from sim.scene import list_scenes


def test_gate_tests_are_one_unit_per_scene_and_the_rest_per_module():
    assert scene_scope("tests/test_gates.py::test_gate[cabinet_door_only-error]") == \
        "tests/test_gates.py::cabinet_door_only"
    assert scene_scope("tests/test_gates.py::test_verdict_is_the_gates[pliers_panda]") == \
        "tests/test_gates.py::pliers_panda"
    assert scene_scope("tests/test_author_gates.py::test_imported_object_meets_the_gate"
                       "[chest-tree]") == "tests/test_author_gates.py::chest"
    # the module's unparametrised test, and other modules: the module
    assert scene_scope("tests/test_gates.py::test_the_gates_run_the_main_jobs_defaults") == \
        "tests/test_gates.py"
    assert scene_scope("tests/test_joints.py::test_revolute[a-b]") == "tests/test_joints.py"
    assert scene_scope("tests/test_sweep.py::TestX::test_y[1]") == "tests/test_sweep.py::TestX"


def test_every_bundled_scene_is_ranked_among_the_long_units():
    """A scene missing from LONGEST_FIRST would start last and run alone at the end."""
    assert set(list_scenes()) <= set(LONGEST_FIRST)
    assert all(m.startswith("tests/test_") for m in PER_SCENE_MODULES)
