"""Fixtures shared across test modules.

The rendered hinge fixture (:mod:`render_fixture`) and its two reconstructions are session-wide:
defined here once, they are rendered and reconstructed once per session for every module that
uses them (defined in each module, pytest treated them as distinct fixtures and rebuilt them per
module: about 7 minutes of CI).
"""

import pytest
import render_fixture


@pytest.fixture(scope="session")
def rendered(tmp_path_factory):
    """Configuration A and B of the hinge fixture, rendered once per session."""
    root = tmp_path_factory.mktemp("hinge")
    return {c: render_fixture.render_set(root / c, c, render_fixture.TEST_VIEWS)
            for c in ("a", "b")}


@pytest.fixture(scope="session")
def reconstruction_sfm(rendered, tmp_path_factory):
    """The whole run, cameras from the images alone (the method's default)."""
    from artrecon import reconstruct

    out = tmp_path_factory.mktemp("run") / "sfm"
    model = reconstruct(rendered["a"].folder, rendered["b"].folder, out_dir=out, progress=False)
    return model, out


@pytest.fixture(scope="session")
def reconstruction_poses(rendered, tmp_path_factory):
    """The whole run with the cameras' known poses (fast path)."""
    from artrecon import reconstruct

    out = tmp_path_factory.mktemp("run") / "poses"
    model = reconstruct(rendered["a"].folder, rendered["b"].folder, poses=True, out_dir=out,
                        progress=False)
    return model, out
